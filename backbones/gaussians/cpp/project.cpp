// Fused per-splat projection of 2DGS surfels and 3DGS ellipsoids, forward and backward.
//
// Ports of the differentiable PyTorch reference code (evaluated in double, stored in the input type):
//   project2d: gs2d/render.py splat_homographies + camera_facing_normals + the screen-position shift
//   project3d: gs3d/render.py project_gaussians + the conics of render_3dgs
// P [C, 4, 4] is raster_camera.pixel_projection: world -> (x w, y w, w, z). Entries s = c * N + n.
// The screen-position leaf enters as a shift of value zero (raster.screen_position_leaf), so the
// forward ignores it and the backward returns its gradient.
#include <cmath>
#include <vector>

#include "api.h"
#include "pool.h"

namespace arcsem {
namespace {

constexpr int64_t kGrain = 1 << 13;  // splats per chunk of the per-splat loops

// raster_camera.quat_to_rotmat (row-major R[3 * i + j]) and its vector-Jacobian product
inline void rotmat(const double q[4], double R[9], double qn[4], double& norm) {
  norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int i = 0; i < 4; ++i) qn[i] = q[i] / norm;
  const double w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z); R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z); R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y); R[7] = 2 * (y * z + w * x); R[8] = 1 - 2 * (x * x + y * y);
}

inline void rotmat_vjp(const double qn[4], double norm, const double g[9], double gq[4]) {
  const double w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  double gn[4];
  gn[0] = 2 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
  gn[1] = 2 * (y * g[1] + z * g[2] + y * g[3] - 2 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2 * x * g[8]);
  gn[2] = 2 * (-2 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2 * y * g[8]);
  gn[3] = 2 * (-2 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2 * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
  const double dot = gn[0] * w + gn[1] * x + gn[2] * y + gn[3] * z;
  for (int i = 0; i < 4; ++i) gq[i] = (gn[i] - qn[i] * dot) / norm;
}

template <typename T>
struct Splat {  // one splat's parameters in double, with its rotation
  double m[3], q[4], s[3], R[9], qn[4], norm;
  Splat(const T* mean, const T* quat, const T* scale, int ns) {
    for (int i = 0; i < 3; ++i) m[i] = mean[i];
    for (int i = 0; i < 4; ++i) q[i] = quat[i];
    for (int i = 0; i < 3; ++i) s[i] = i < ns ? double(scale[i]) : 0.0;
    rotmat(q, R, qn, norm);
  }
};

// 2DGS homography rows Tu, Tv, Tw, Tz (12 values): H[i][k] = sum_j P[i][j] S[j][k], S = [R0 s0, R1 s1, (m, 1)]
template <typename T>
inline void homography(const Splat<T>& sp, const double* P, double Hm[12]) {
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

// 3DGS EWA: pixel centre, depth, Jacobian Jw [2x3], JM = Jw R S [2x3], cov (a, b, c) with the 0.3 blur
struct Ewa {
  double hom[4], w, m2[2], Jw[6], JM[6], cov[3];
};

template <typename T>
inline void ewa(const Splat<T>& sp, const double* P, Ewa& e) {
  for (int i = 0; i < 4; ++i) e.hom[i] = P[4 * i] * sp.m[0] + P[4 * i + 1] * sp.m[1] + P[4 * i + 2] * sp.m[2] + P[4 * i + 3];
  e.w = e.hom[2];
  e.m2[0] = e.hom[0] / e.w;
  e.m2[1] = e.hom[1] / e.w;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) e.Jw[3 * i + j] = (P[4 * i + j] - e.m2[i] * P[8 + j]) / e.w;
  for (int i = 0; i < 2; ++i)
    for (int k = 0; k < 3; ++k)
      e.JM[3 * i + k] = (e.Jw[3 * i] * sp.R[k] + e.Jw[3 * i + 1] * sp.R[3 + k] + e.Jw[3 * i + 2] * sp.R[6 + k]) * sp.s[k];
  const double* J = e.JM;
  e.cov[0] = J[0] * J[0] + J[1] * J[1] + J[2] * J[2] + 0.3;
  e.cov[1] = J[0] * J[3] + J[1] * J[4] + J[2] * J[5];
  e.cov[2] = J[3] * J[3] + J[4] * J[4] + J[5] * J[5] + 0.3;
}

// footprint_3dgs validity of the conic, from the stored (rounded) covariance and depth
template <typename T>
inline bool conic_ok(const T* cov, T depth, double near) {
  const double a = cov[0], b = cov[1], c = cov[2];
  const double det = a * c - b * b, mid = 0.5 * (a + c);
  return det > 0 && depth > T(near) && std::isfinite(mid + std::sqrt(std::max(mid * mid - det, 0.1)));
}

void check(const at::Tensor& t) { TORCH_CHECK(t.is_contiguous() && t.device().is_cpu(), "project: inputs must be contiguous CPU tensors"); }

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
        const Splat<scalar_t> sp(m + 3 * n, q + 4 * n, sc + 2 * n, 2);
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
        const Splat<scalar_t> sp(m + 3 * n, q + 4 * n, sc + 2 * n, 2);
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
        rotmat_vjp(sp.qn, sp.norm, gR, gquat);
        for (int j = 0; j < 3; ++j) om[3 * n + j] = scalar_t(gmean[j]);
        for (int j = 0; j < 4; ++j) oq[4 * n + j] = scalar_t(gquat[j]);
        for (int j = 0; j < 2; ++j) os[2 * n + j] = scalar_t(gscale[j]);
      }
    });
  });
  return {gm, gq, gs, gsh};
}

// -> means2d [C*N, 2], depth [C*N], conics [C*N, 3], cov (a, b, c) [C*N, 3]
std::vector<at::Tensor> project3d_forward(const Projection& pr) {
  const auto &means = pr.means, &quats = pr.quats, &scales = pr.scales, &P = pr.P;
  const double near = pr.near;
  for (auto* t : {&means, &quats, &scales, &P}) check(*t);
  const int64_t N = means.size(0), C = P.size(0);
  auto o = means.options();
  auto m2 = at::empty({C * N, 2}, o), dep = at::empty({C * N}, o), con = at::empty({C * N, 3}, o),
       cov = at::empty({C * N, 3}, o);
  auto Pd = P.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project3d_forward", [&] {
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *sc = scales.data_ptr<scalar_t>();
    scalar_t *om = m2.data_ptr<scalar_t>(), *od = dep.data_ptr<scalar_t>(), *oc = con.data_ptr<scalar_t>(),
             *ov = cov.data_ptr<scalar_t>();
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      for (int64_t n = b; n < e; ++n) {
        const Splat<scalar_t> sp(m + 3 * n, q + 4 * n, sc + 3 * n, 3);
        for (int64_t c = 0; c < C; ++c) {
          const int64_t s = c * N + n;
          Ewa E;
          ewa(sp, Pd.data_ptr<double>() + 16 * c, E);
          om[2 * s] = scalar_t(E.m2[0]);
          om[2 * s + 1] = scalar_t(E.m2[1]);
          od[s] = scalar_t(E.hom[3]);
          for (int j = 0; j < 3; ++j) ov[3 * s + j] = scalar_t(E.cov[j]);
          const double a = ov[3 * s], bb = ov[3 * s + 1], cc = ov[3 * s + 2];
          const double det = conic_ok(ov + 3 * s, od[s], near) ? a * cc - bb * bb : 1.0;
          oc[3 * s] = scalar_t(cc / det);
          oc[3 * s + 1] = scalar_t(-bb / det);
          oc[3 * s + 2] = scalar_t(a / det);
        }
      }
    });
  });
  return {m2, dep, con, cov};
}

// -> g_means [N,3], g_quats [N,4], g_scales [N,3], g_shift [C*N, 2] (= g_means2d)
std::vector<at::Tensor> project3d_backward(const Projection& pr, const at::Tensor& gm2, const at::Tensor& gdep,
                                              const at::Tensor& gcon) {
  const auto &means = pr.means, &quats = pr.quats, &scales = pr.scales, &P = pr.P;
  const double near = pr.near;
  for (auto* t : {&means, &quats, &scales, &P, &gm2, &gdep, &gcon}) check(*t);
  const int64_t N = means.size(0), C = P.size(0);
  auto gm = at::empty_like(means), gq = at::empty_like(quats), gs = at::empty_like(scales);
  auto Pd = P.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project3d_backward", [&] {
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *sc = scales.data_ptr<scalar_t>();
    const scalar_t *G2 = gm2.data_ptr<scalar_t>(), *GD = gdep.data_ptr<scalar_t>(), *GC = gcon.data_ptr<scalar_t>();
    scalar_t *om = gm.data_ptr<scalar_t>(), *oq = gq.data_ptr<scalar_t>(), *os = gs.data_ptr<scalar_t>();
    parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) {
      for (int64_t n = b; n < e; ++n) {
        const Splat<scalar_t> sp(m + 3 * n, q + 4 * n, sc + 3 * n, 3);
        double gR[9] = {0}, gmean[3] = {0}, gscale[3] = {0};
        for (int64_t c = 0; c < C; ++c) {
          const int64_t s = c * N + n;
          const double* Pc = Pd.data_ptr<double>() + 16 * c;
          Ewa E;
          ewa(sp, Pc, E);
          const scalar_t covT[3] = {scalar_t(E.cov[0]), scalar_t(E.cov[1]), scalar_t(E.cov[2])};
          const double a = covT[0], bb = covT[1], cc = covT[2];
          const double gca = GC[3 * s], gcb = GC[3 * s + 1], gcc = GC[3 * s + 2];
          double ga = gcc, gb = -gcb, gc = gca;  // conic = (c, -b, a) / det
          if (conic_ok(covT, scalar_t(E.hom[3]), near)) {
            const double inv = 1.0 / (a * cc - bb * bb);
            const double gdet = -inv * inv * (gca * cc - gcb * bb + gcc * a);
            ga = gcc * inv + gdet * cc;
            gc = gca * inv + gdet * a;
            gb = -gcb * inv - 2.0 * bb * gdet;
          }
          double gJM[6], gJw[6] = {0}, g2[2] = {double(G2[2 * s]), double(G2[2 * s + 1])}, gw = 0;
          for (int k = 0; k < 3; ++k) {  // cov = JM JM^T: g_JM = (G + G^T) JM, G = [[ga, gb], [0, gc]]
            gJM[k] = 2 * ga * E.JM[k] + gb * E.JM[3 + k];
            gJM[3 + k] = gb * E.JM[k] + 2 * gc * E.JM[3 + k];
          }
          for (int i = 0; i < 2; ++i)  // JM[i][k] = sum_j Jw[i][j] R[j][k] s[k]
            for (int k = 0; k < 3; ++k)
              for (int j = 0; j < 3; ++j) {
                gJw[3 * i + j] += gJM[3 * i + k] * sp.R[3 * j + k] * sp.s[k];
                gR[3 * j + k] += gJM[3 * i + k] * E.Jw[3 * i + j] * sp.s[k];
                gscale[k] += gJM[3 * i + k] * E.Jw[3 * i + j] * sp.R[3 * j + k];
              }
          for (int i = 0; i < 2; ++i)  // Jw[i][j] = (P[i][j] - m2[i] P[2][j]) / w
            for (int j = 0; j < 3; ++j) {
              g2[i] -= gJw[3 * i + j] * Pc[8 + j] / E.w;
              gw -= gJw[3 * i + j] * E.Jw[3 * i + j] / E.w;
            }
          gw -= (g2[0] * E.m2[0] + g2[1] * E.m2[1]) / E.w;
          const double ghom[4] = {g2[0] / E.w, g2[1] / E.w, gw, double(GD[s])};
          for (int j = 0; j < 3; ++j)
            gmean[j] += Pc[j] * ghom[0] + Pc[4 + j] * ghom[1] + Pc[8 + j] * ghom[2] + Pc[12 + j] * ghom[3];
        }
        double gquat[4];
        rotmat_vjp(sp.qn, sp.norm, gR, gquat);
        for (int j = 0; j < 3; ++j) om[3 * n + j] = scalar_t(gmean[j]);
        for (int j = 0; j < 4; ++j) oq[4 * n + j] = scalar_t(gquat[j]);
        for (int j = 0; j < 3; ++j) os[3 * n + j] = scalar_t(gscale[j]);
      }
    });
  });
  return {gm, gq, gs, gm2.clone()};
}

}  // namespace arcsem
