// Densification statistics of one step, fused (backbones/gaussians/densify.py is the reference:
// screen_grad_norms + DensifyStats.accumulate). Per (camera c, splat n) visible in c:
//   g_cam = R_c g_n (g: dL/d mean), z = camera depth of the mean (pinhole; orthographic: 1)
//   norm = |(g_cam.x z / fx W / 2, g_cam.y z / fy H / 2)|      (the image-plane NDC gradient)
//   grad_sum[n] += norm, count[n] += 1, max_radii[n] = max(max_radii[n], radii[c, n])
// One pass over the splats in the kernels' pool instead of about twenty tensor operations.
#include "api.h"
#include "pool.h"

namespace arcsem {
namespace {

template <typename T>
void accumulate(const DensifyStatsIn& a, int64_t b, int64_t e) {
  const int64_t C = a.w2c.size(0), N = a.grad_means.size(0);
  const T *g = a.grad_means.data_ptr<T>(), *m = a.means.data_ptr<T>();
  const double *w2c = a.w2c.data_ptr<double>(), *K = a.K.data_ptr<double>();
  const bool* vis = a.visible.data_ptr<bool>();
  const int64_t* radii = a.radii.data_ptr<int64_t>();
  float *gs = a.grad_sum.data_ptr<float>(), *cnt = a.count.data_ptr<float>(), *mr = a.max_radii.data_ptr<float>();
  for (int64_t n = b; n < e; ++n) {
    double sum = 0, seen = 0, rmax = mr[n];
    for (int64_t c = 0; c < C; ++c) {
      if (!vis[c * N + n]) continue;
      const double* Rt = w2c + 16 * c;  // rows of [R | t]
      double gc[2], z = 1.0;
      for (int i = 0; i < 2; ++i) gc[i] = Rt[4 * i] * g[3 * n] + Rt[4 * i + 1] * g[3 * n + 1] + Rt[4 * i + 2] * g[3 * n + 2];
      if (!a.ortho) z = Rt[8] * m[3 * n] + Rt[9] * m[3 * n + 1] + Rt[10] * m[3 * n + 2] + Rt[11];
      const double gu = gc[0] * z / K[9 * c] * (double(a.W) / 2), gv = gc[1] * z / K[9 * c + 4] * (double(a.H) / 2);
      sum += std::sqrt(gu * gu + gv * gv);
      seen += 1;
      rmax = std::max(rmax, double(radii[c * N + n]));
    }
    gs[n] += float(sum);
    cnt[n] += float(seen);
    mr[n] = float(rmax);
  }
}

}  // namespace

void densify_stats(const DensifyStatsIn& a) {
  for (auto* t : {&a.grad_means, &a.means, &a.w2c, &a.K, &a.visible, &a.radii, &a.grad_sum, &a.count, &a.max_radii})
    TORCH_CHECK(t->is_contiguous() && t->device().is_cpu(), "densify_stats: inputs must be contiguous CPU tensors");
  TORCH_CHECK(a.w2c.scalar_type() == at::kDouble && a.K.scalar_type() == at::kDouble, "densify_stats: cameras in float64");
  TORCH_CHECK(a.visible.scalar_type() == at::kBool && a.radii.scalar_type() == at::kLong, "densify_stats: visible bool, radii long");
  for (auto* t : {&a.grad_sum, &a.count, &a.max_radii})
    TORCH_CHECK(t->scalar_type() == at::kFloat, "densify_stats: the accumulators are float32");
  AT_DISPATCH_FLOATING_TYPES(a.grad_means.scalar_type(), "densify_stats", [&] {
    parallel_range(a.grad_means.size(0), 1 << 13, [&](int64_t b, int64_t e, int) { accumulate<scalar_t>(a, b, e); });
  });
}

}  // namespace arcsem
