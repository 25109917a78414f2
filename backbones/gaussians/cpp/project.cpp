// Fused per-splat projection of 2DGS surfels, forward and backward (conventions: project.h).
//
// Ports of gs2d/render.py splat_homographies + camera_facing_normals + the screen-position shift. The screen-position
// leaf enters as a shift of value zero (raster.screen_position_leaf), so the forward ignores it and the backward
// returns its gradient.
#include <vector>

#include "pool.h"
#include "project.h"

namespace arcsem {
namespace {

using proj::check;
using proj::kGrain;
using Splat = proj::Splat<double>;

// a surfel's parameters (means, quats [4], scales [2]) in double
template <typename T>
Splat splat2d(const T* mean, const T* quat, const T* scale) {
  const double m[3] = {mean[0], mean[1], mean[2]}, q[4] = {quat[0], quat[1], quat[2], quat[3]},
               s[3] = {scale[0], scale[1], 0.0};
  return Splat(m, q, s);
}

// 2DGS homography rows Tu, Tv, Tw, Tz (12 values): H[i][k] = sum_j P[i][j] S[j][k], S = [R0 s0, R1 s1, (m, 1)]
inline void homography(const Splat& sp, const double* P, double Hm[12]) {
  for (int i = 0; i < 4; ++i) {
    const double* p = P + 4 * i;
    Hm[3 * i] = (p[0] * sp.R[0] + p[1] * sp.R[3] + p[2] * sp.R[6]) * sp.s[0];
    Hm[3 * i + 1] = (p[0] * sp.R[1] + p[1] * sp.R[4] + p[2] * sp.R[7]) * sp.s[1];
    Hm[3 * i + 2] = p[0] * sp.m[0] + p[1] * sp.m[1] + p[2] * sp.m[2] + p[3];
  }
}

// camera_facing_normals: +1 or -1 for column 2 of R
inline double facing(const double* R, const double* m, const double* view, bool ortho) {
  double v[3];
  for (int j = 0; j < 3; ++j) v[j] = ortho ? view[j] : m[j] - view[j];
  return R[2] * v[0] + R[5] * v[1] + R[8] * v[2] > 0 ? -1.0 : 1.0;
}

}  // namespace

// -> H [C*N, 9] (rows Tu, Tv, Tw), Dz [C*N, 3] (row Tz), centre [C*N, 2], normals [C*N, 3]
std::vector<at::Tensor> project2d_forward(const Projection& pr) {
  const auto &means = pr.means, &quats = pr.quats, &scales = pr.scales, &P = pr.P, &view = pr.view;
  const bool ortho = pr.ortho;
  for (auto* t : {&means, &quats, &scales, &P, &view}) check(*t);
  const int64_t N = means.size(0), C = P.size(0);
  auto o = means.options();
  auto Hm = at::empty({C * N, 9}, o), Dz = at::empty({C * N, 3}, o), ctr = at::empty({C * N, 2}, o), nrm = at::empty({C * N, 3}, o);
  auto Pd = P.to(at::kDouble).contiguous(), Vd = view.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project2d_forward", [&] {
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *sc = scales.data_ptr<scalar_t>();
    scalar_t *H = Hm.data_ptr<scalar_t>(), *Z = Dz.data_ptr<scalar_t>(), *ct = ctr.data_ptr<scalar_t>(), *nr = nrm.data_ptr<scalar_t>();
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      for (int64_t n = b; n < e; ++n) {
        const Splat sp = splat2d(m + 3 * n, q + 4 * n, sc + 2 * n);
        for (int64_t c = 0; c < C; ++c) {
          const int64_t s = c * N + n;
          double h[12];
          homography(sp, Pd.data_ptr<double>() + 16 * c, h);
          for (int j = 0; j < 9; ++j) H[9 * s + j] = scalar_t(h[j]);
          for (int j = 0; j < 3; ++j) Z[3 * s + j] = scalar_t(h[9 + j]);
          ct[2 * s] = H[9 * s + 2] / H[9 * s + 8];  // in the storage type, as the reference
          ct[2 * s + 1] = H[9 * s + 5] / H[9 * s + 8];
          const double sg = facing(sp.R, sp.m, Vd.data_ptr<double>() + 3 * c, ortho);
          for (int j = 0; j < 3; ++j) nr[3 * s + j] = scalar_t(sg * sp.R[3 * j + 2]);
        }
      }
    });
  });
  return {Hm, Dz, ctr, nrm};
}

// -> g_means [N,3], g_quats [N,4], g_scales [N,2], g_shift [C*N, 2]
std::vector<at::Tensor> project2d_backward(const Projection& pr, const at::Tensor& gH, const at::Tensor& gDz,
                                              const at::Tensor& gctr, const at::Tensor& gnrm) {
  const auto &means = pr.means, &quats = pr.quats, &scales = pr.scales, &P = pr.P, &view = pr.view;
  const bool ortho = pr.ortho;
  for (auto* t : {&means, &quats, &scales, &P, &view, &gH, &gDz, &gctr, &gnrm}) check(*t);
  const int64_t N = means.size(0), C = P.size(0);
  auto gm = at::empty_like(means), gq = at::empty_like(quats), gs = at::empty_like(scales);
  auto gsh = at::empty({C * N, 2}, means.options());
  auto Pd = P.to(at::kDouble).contiguous(), Vd = view.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project2d_backward", [&] {
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *sc = scales.data_ptr<scalar_t>();
    const scalar_t *GH = gH.data_ptr<scalar_t>(), *GZ = gDz.data_ptr<scalar_t>(), *GC = gctr.data_ptr<scalar_t>(), *GN = gnrm.data_ptr<scalar_t>();
    scalar_t *om = gm.data_ptr<scalar_t>(), *oq = gq.data_ptr<scalar_t>(), *os = gs.data_ptr<scalar_t>();
    scalar_t* osh = gsh.data_ptr<scalar_t>();
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      for (int64_t n = b; n < e; ++n) {
        const Splat sp = splat2d(m + 3 * n, q + 4 * n, sc + 2 * n);
        double gR[9] = {0}, gmean[3] = {0}, gscale[2] = {0};
        for (int64_t c = 0; c < C; ++c) {
          const int64_t s = c * N + n;
          const double* Pc = Pd.data_ptr<double>() + 16 * c;
          double h[12], g[12];
          homography(sp, Pc, h);
          for (int j = 0; j < 9; ++j) g[j] = GH[9 * s + j];
          for (int j = 0; j < 3; ++j) g[9 + j] = GZ[3 * s + j];
          // centre = (Tu.z / Tw.z, Tv.z / Tw.z) of the rounded homography
          const double tw = scalar_t(h[8]), cx = double(scalar_t(h[2])) / tw, cy = double(scalar_t(h[5])) / tw;
          g[2] += GC[2 * s] / tw;
          g[5] += GC[2 * s + 1] / tw;
          g[8] -= (GC[2 * s] * cx + GC[2 * s + 1] * cy) / tw;
          // Tu += sx Tw, Tv += sy Tw (sx = sy = 0 in value)
          osh[2 * s] = scalar_t(g[0] * h[6] + g[1] * h[7] + g[2] * h[8]);
          osh[2 * s + 1] = scalar_t(g[3] * h[6] + g[4] * h[7] + g[5] * h[8]);
          for (int j = 0; j < 3; ++j) {  // g_S[j][k] = sum_i P[i][j] g[i][k]
            double gS[3];
            for (int k = 0; k < 3; ++k) gS[k] = Pc[j] * g[k] + Pc[4 + j] * g[3 + k] + Pc[8 + j] * g[6 + k] + Pc[12 + j] * g[9 + k];
            gR[3 * j] += gS[0] * sp.s[0];
            gR[3 * j + 1] += gS[1] * sp.s[1];
            gscale[0] += gS[0] * sp.R[3 * j];
            gscale[1] += gS[1] * sp.R[3 * j + 1];
            gmean[j] += gS[2];
          }
          const double sg = facing(sp.R, sp.m, Vd.data_ptr<double>() + 3 * c, ortho);
          for (int j = 0; j < 3; ++j) gR[3 * j + 2] += sg * GN[3 * s + j];
        }
        double gquat[4];
        proj::rotmat_vjp(sp.qn, sp.norm, gR, gquat);
        for (int j = 0; j < 3; ++j) om[3 * n + j] = scalar_t(gmean[j]);
        for (int j = 0; j < 4; ++j) oq[4 * n + j] = scalar_t(gquat[j]);
        for (int j = 0; j < 2; ++j) os[2 * n + j] = scalar_t(gscale[j]);
      }
    });
  });
  return {gm, gq, gs, gsh};
}

}  // namespace arcsem
