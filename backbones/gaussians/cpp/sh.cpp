// Spherical-harmonics colours of every (camera, splat), forward and backward, fused (backbones/gaussians/sh.py is the
// reference: the same basis, normalisation and clamp).
//   dir = normalize(mean - centre) (pinhole) or the camera's forward axis (orthographic); F.normalize's eps 1e-12
//   rgb = max(sum_k sh[k] Y_k(dir) + 0.5, 0) over the first (degree + 1)^2 coefficients
// Parallel over splats (each handles its cameras), so sums over cameras have a fixed order.
#include <cmath>

#include "api.h"
#include "pool.h"

namespace arcsem {
namespace {

constexpr double C0 = 0.28209479177387814, C1 = 0.4886025119029199;
constexpr double C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                          0.5462742152960396};
constexpr double C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                          -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// Y_k(d) for k < (degree + 1)^2 and, when dY is given, dY_k / d(x, y, z) (dY[3 k + a])
template <typename T>
void basis(int degree, T x, T y, T z, T* Y, T* dY) {
  Y[0] = T(C0);
  if (dY) dY[0] = dY[1] = dY[2] = T(0);
  if (degree < 1) return;
  Y[1] = T(-C1) * y; Y[2] = T(C1) * z; Y[3] = T(-C1) * x;
  if (dY) {
    const T d1[9] = {0, T(-C1), 0, 0, 0, T(C1), T(-C1), 0, 0};
    for (int i = 0; i < 9; ++i) dY[3 + i] = d1[i];
  }
  if (degree < 2) return;
  const T xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  Y[4] = T(C2[0]) * xy; Y[5] = T(C2[1]) * yz; Y[6] = T(C2[2]) * (2 * zz - xx - yy); Y[7] = T(C2[3]) * xz;
  Y[8] = T(C2[4]) * (xx - yy);
  if (dY) {
    const T d2[15] = {T(C2[0]) * y, T(C2[0]) * x, 0,
                      0, T(C2[1]) * z, T(C2[1]) * y,
                      T(C2[2]) * -2 * x, T(C2[2]) * -2 * y, T(C2[2]) * 4 * z,
                      T(C2[3]) * z, 0, T(C2[3]) * x,
                      T(C2[4]) * 2 * x, T(C2[4]) * -2 * y, 0};
    for (int i = 0; i < 15; ++i) dY[12 + i] = d2[i];
  }
  if (degree < 3) return;
  Y[9] = T(C3[0]) * y * (3 * xx - yy);
  Y[10] = T(C3[1]) * xy * z;
  Y[11] = T(C3[2]) * y * (4 * zz - xx - yy);
  Y[12] = T(C3[3]) * z * (2 * zz - 3 * xx - 3 * yy);
  Y[13] = T(C3[4]) * x * (4 * zz - xx - yy);
  Y[14] = T(C3[5]) * z * (xx - yy);
  Y[15] = T(C3[6]) * x * (xx - 3 * yy);
  if (dY) {
    const T d3[21] = {T(C3[0]) * 6 * xy, T(C3[0]) * (3 * xx - 3 * yy), 0,
                      T(C3[1]) * yz, T(C3[1]) * xz, T(C3[1]) * xy,
                      T(C3[2]) * -2 * xy, T(C3[2]) * (4 * zz - xx - 3 * yy), T(C3[2]) * 8 * yz,
                      T(C3[3]) * -6 * xz, T(C3[3]) * -6 * yz, T(C3[3]) * (6 * zz - 3 * xx - 3 * yy),
                      T(C3[4]) * (4 * zz - 3 * xx - yy), T(C3[4]) * -2 * xy, T(C3[4]) * 8 * xz,
                      T(C3[5]) * 2 * xz, T(C3[5]) * -2 * yz, T(C3[5]) * (xx - yy),
                      T(C3[6]) * (3 * xx - 3 * yy), T(C3[6]) * -6 * xy, 0};
    for (int i = 0; i < 21; ++i) dY[27 + i] = d3[i];
  }
}

// the viewing direction of splat mean m from camera c, normalised (F.normalize: v / max(|v|, 1e-12)); |v| in len
template <typename T>
inline void direction(const ShColors& a, const T* m, const T* origin, T* d, T& len) {
  T v[3];
  for (int i = 0; i < 3; ++i) v[i] = a.ortho ? origin[i] : m[i] - origin[i];
  len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  const T den = std::max(len, T(1e-12));
  for (int i = 0; i < 3; ++i) d[i] = v[i] / den;
}

constexpr int64_t kGrain = 1024;  // splats per chunk

}  // namespace

at::Tensor sh_colors_forward(const ShColors& a) {
  for (auto* t : {&a.means, &a.sh_dc, &a.sh_rest, &a.origins}) TORCH_CHECK(t->is_contiguous(), "sh_colors: inputs must be contiguous");
  const int64_t N = a.means.size(0), C = a.origins.size(0), K = (a.degree + 1) * (a.degree + 1), R = a.sh_rest.size(1);
  TORCH_CHECK(a.degree >= 0 && a.degree <= 3 && K - 1 <= R, "sh_colors: degree ", a.degree, " needs ", K - 1, " rest coefficients");
  auto out = at::empty({C, N, 3}, a.means.options());
  AT_DISPATCH_FLOATING_TYPES(a.means.scalar_type(), "sh_colors_forward", [&] {
    using T = scalar_t;
    const T *m = a.means.data_ptr<T>(), *dc = a.sh_dc.data_ptr<T>(), *rest = a.sh_rest.data_ptr<T>(), *o = a.origins.data_ptr<T>();
    T* rgb = out.data_ptr<T>();
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      T Y[16], d[3], len;
      for (int64_t n = b; n < e; ++n)
        for (int64_t c = 0; c < C; ++c) {
          direction(a, m + 3 * n, o + 3 * c, d, len);
          basis<T>(int(a.degree), d[0], d[1], d[2], Y, nullptr);
          for (int ch = 0; ch < 3; ++ch) {
            T s = Y[0] * dc[3 * n + ch];
            for (int64_t k = 1; k < K; ++k) s += Y[k] * rest[(n * R + k - 1) * 3 + ch];
            rgb[(c * N + n) * 3 + ch] = std::max(s + T(0.5), T(0));
          }
        }
    });
  });
  return out;
}

std::vector<at::Tensor> sh_colors_backward(const ShColors& a, const at::Tensor& g_colors) {
  const int64_t N = a.means.size(0), C = a.origins.size(0), K = (a.degree + 1) * (a.degree + 1), R = a.sh_rest.size(1);
  // every entry is written below (unused rest coefficients get 0): no zero fill of [N, 15, 3] first
  auto gm = at::empty_like(a.means), gdc = at::empty_like(a.sh_dc), grest = at::empty_like(a.sh_rest);
  auto g_in = g_colors.contiguous();
  AT_DISPATCH_FLOATING_TYPES(a.means.scalar_type(), "sh_colors_backward", [&] {
    using T = scalar_t;
    const T *m = a.means.data_ptr<T>(), *dc = a.sh_dc.data_ptr<T>(), *rest = a.sh_rest.data_ptr<T>(), *o = a.origins.data_ptr<T>();
    const T* g = g_in.data_ptr<T>();
    T *om = gm.data_ptr<T>(), *odc = gdc.data_ptr<T>(), *orest = grest.data_ptr<T>();
    const bool want_dir = !a.ortho && a.degree > 0;
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      T Y[16], dY[48], d[3], len;
      for (int64_t n = b; n < e; ++n) {
        T gsh[16][3] = {};
        T gv[3] = {0, 0, 0};
        for (int64_t c = 0; c < C; ++c) {
          direction(a, m + 3 * n, o + 3 * c, d, len);
          basis<T>(int(a.degree), d[0], d[1], d[2], Y, want_dir ? dY : nullptr);
          T gc[3];
          for (int ch = 0; ch < 3; ++ch) {  // clamp_min(x, 0) passes the gradient where x >= 0
            T sum = Y[0] * dc[3 * n + ch];
            for (int64_t k = 1; k < K; ++k) sum += Y[k] * rest[(n * R + k - 1) * 3 + ch];
            gc[ch] = sum + T(0.5) >= T(0) ? g[(c * N + n) * 3 + ch] : T(0);
          }
          for (int64_t k = 0; k < K; ++k)
            for (int ch = 0; ch < 3; ++ch) gsh[k][ch] += Y[k] * gc[ch];
          if (!want_dir) continue;
          T gd[3] = {0, 0, 0};
          for (int64_t k = 1; k < K; ++k) {
            const T* cf = rest + (n * R + k - 1) * 3;
            const T gb = cf[0] * gc[0] + cf[1] * gc[1] + cf[2] * gc[2];
            for (int ax = 0; ax < 3; ++ax) gd[ax] += gb * dY[3 * k + ax];
          }
          const T dot = len > T(1e-12) ? gd[0] * d[0] + gd[1] * d[1] + gd[2] * d[2] : T(0);
          const T den = std::max(len, T(1e-12));  // d = v / max(|v|, eps): dd/dv = (I - d d^T) / |v| above eps
          for (int ax = 0; ax < 3; ++ax) gv[ax] += (gd[ax] - d[ax] * dot) / den;
        }
        for (int ch = 0; ch < 3; ++ch) odc[3 * n + ch] = gsh[0][ch];
        for (int64_t k = 1; k < K; ++k)
          for (int ch = 0; ch < 3; ++ch) orest[(n * R + k - 1) * 3 + ch] = gsh[k][ch];
        std::fill(orest + (n * R + K - 1) * 3, orest + (n + 1) * R * 3, T(0));  // coefficients above the degree
        for (int ax = 0; ax < 3; ++ax) om[3 * n + ax] = gv[ax];
      }
    });
  });
  return {gm, gdc, grest};
}

}  // namespace arcsem
