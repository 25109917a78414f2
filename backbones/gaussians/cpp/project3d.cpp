// Fused per-splat projection of 3DGS ellipsoids, forward and backward (conventions: project.h).
//
// A port of gs3d/render.py project_gaussians + the conics of render_3dgs, on kL splats at once (proj::Lanes).
#include <limits>
#include <vector>

#include "pool.h"
#include "project.h"

namespace arcsem {
namespace {

using proj::kL;
using proj::Lanes;
using proj::Mask;
using proj::splat;
using proj::stored;
using proj::Splat;

// EWA: pixel centre, depth, Jacobian Jw [2x3], JM = Jw R S [2x3], cov (a, b, c) with the 0.3 blur
struct Ewa {
  Lanes hom[4], w, m2[2], Jw[6], JM[6], cov[3];
};

inline void ewa(const Splat& sp, const double* P, Ewa& e) {
  for (int i = 0; i < 4; ++i) e.hom[i] = P[4 * i] * sp.m[0] + P[4 * i + 1] * sp.m[1] + P[4 * i + 2] * sp.m[2] + P[4 * i + 3];
  e.w = e.hom[2];
  e.m2[0] = e.hom[0] / e.w;
  e.m2[1] = e.hom[1] / e.w;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) e.Jw[3 * i + j] = (P[4 * i + j] - e.m2[i] * P[8 + j]) / e.w;
  for (int i = 0; i < 2; ++i)
    for (int k = 0; k < 3; ++k)
      e.JM[3 * i + k] = (e.Jw[3 * i] * sp.R[k] + e.Jw[3 * i + 1] * sp.R[3 + k] + e.Jw[3 * i + 2] * sp.R[6 + k]) * sp.s[k];
  const Lanes* J = e.JM;
  e.cov[0] = J[0] * J[0] + J[1] * J[1] + J[2] * J[2] + 0.3;
  e.cov[1] = J[0] * J[3] + J[1] * J[4] + J[2] * J[5];
  e.cov[2] = J[3] * J[3] + J[4] * J[4] + J[5] * J[5] + 0.3;
}

// footprint_3dgs validity of the conic, from the stored (rounded) covariance and depth; near as stored (T(near))
inline Mask conic_ok(const Lanes* cov, Lanes depth, double near) {
  const Lanes det = cov[0] * cov[2] - cov[1] * cov[1], mid = 0.5 * (cov[0] + cov[2]), d = mid * mid - det;
  const Lanes r = mid + proj::vsqrt(d < 0.1 ? splat(0.1) : d);  // std::max(d, 0.1), NaN kept
  const double big = std::numeric_limits<double>::max();
  return (det > 0) & (depth > near) & (r <= big) & (r >= -big);  // (r finite)
}

template <typename T>
struct P3 {  // a projection's inputs: means [N, 3], quats [N, 4], scales [N, 3], P [C, 16] (double)
  const T *m, *q, *sc;
  const double* P;
  int64_t N, C;
  double near;  // as stored: double(T(near))
};

template <typename T>
void forward_range(const P3<T>& a, int64_t b, int64_t e, T* om, T* od, T* oc, T* ov) {
  for (int64_t n0 = b; n0 < e; n0 += kL) {
    const int nb = int(std::min<int64_t>(kL, e - n0));
    const Splat sp = proj::load_splats(a.m, a.q, a.sc, 3, n0, nb);
    for (int64_t c = 0; c < a.C; ++c) {
      Ewa E;
      ewa(sp, a.P + 16 * c, E);
      const Lanes cv[3] = {stored<T>(E.cov[0]), stored<T>(E.cov[1]), stored<T>(E.cov[2])}, depth = stored<T>(E.hom[3]);
      const Lanes det = conic_ok(cv, depth, a.near) ? cv[0] * cv[2] - cv[1] * cv[1] : splat(1.0);
      const Lanes out[9] = {E.m2[0], E.m2[1], depth, cv[0], cv[1], cv[2], cv[2] / det, -cv[1] / det, cv[0] / det};
      for (int i = 0; i < nb; ++i) {
        const int64_t s = c * a.N + n0 + i;
        om[2 * s] = T(out[0][i]); om[2 * s + 1] = T(out[1][i]); od[s] = T(out[2][i]);
        for (int j = 0; j < 3; ++j) ov[3 * s + j] = T(out[3 + j][i]);
        for (int j = 0; j < 3; ++j) oc[3 * s + j] = T(out[6 + j][i]);
      }
    }
  }
}

// the gradients of splats [b, e) from those of means2d (G2), depth (GD) and conics (GC)
template <typename T>
void backward_range(const P3<T>& a, const T* G2, const T* GD, const T* GC, int64_t b, int64_t e, T* om, T* oq, T* os) {
  for (int64_t n0 = b; n0 < e; n0 += kL) {
    const int nb = int(std::min<int64_t>(kL, e - n0));
    const Splat sp = proj::load_splats(a.m, a.q, a.sc, 3, n0, nb);
    Lanes gR[9] = {}, gmean[3] = {}, gscale[3] = {};  // sums over the cameras
    for (int64_t c = 0; c < a.C; ++c) {
      const double* Pc = a.P + 16 * c;
      Lanes g[6];  // this camera's gradients of means2d (2), depth, conic (3)
      for (int i = 0; i < kL; ++i) {
        const int64_t s = c * a.N + n0 + std::min(i, nb - 1);
        g[0][i] = G2[2 * s]; g[1][i] = G2[2 * s + 1]; g[2][i] = GD[s];
        for (int j = 0; j < 3; ++j) g[3 + j][i] = GC[3 * s + j];
      }
      Ewa E;
      ewa(sp, Pc, E);
      const Lanes cv[3] = {stored<T>(E.cov[0]), stored<T>(E.cov[1]), stored<T>(E.cov[2])};
      const Lanes &gca = g[3], &gcb = g[4], &gcc = g[5];
      // conic = (c, -b, a) / det, or (c, -b, a) where the conic was not inverted
      const Mask inverted = conic_ok(cv, stored<T>(E.hom[3]), a.near);
      const Lanes inv = inverted ? 1.0 / (cv[0] * cv[2] - cv[1] * cv[1]) : splat(1.0);
      const Lanes gdet = -inv * inv * (gca * cv[2] - gcb * cv[1] + gcc * cv[0]);
      const Lanes ga = inverted ? gcc * inv + gdet * cv[2] : gcc, gc = inverted ? gca * inv + gdet * cv[0] : gca,
                  gb = inverted ? -gcb * inv - 2.0 * cv[1] * gdet : -gcb;
      Lanes gJM[6], gJw[6] = {}, g2[2] = {g[0], g[1]}, gw = {};
      for (int k = 0; k < 3; ++k) {  // cov = JM JM^T: g_JM = (G + G^T) JM, G = [[ga, gb], [0, gc]]
        gJM[k] = 2 * ga * E.JM[k] + gb * E.JM[3 + k];
        gJM[3 + k] = gb * E.JM[k] + 2 * gc * E.JM[3 + k];
      }
      for (int r = 0; r < 2; ++r)  // JM[r][k] = sum_j Jw[r][j] R[j][k] s[k]
        for (int k = 0; k < 3; ++k)
          for (int j = 0; j < 3; ++j) {
            gJw[3 * r + j] += gJM[3 * r + k] * sp.R[3 * j + k] * sp.s[k];
            gR[3 * j + k] += gJM[3 * r + k] * E.Jw[3 * r + j] * sp.s[k];
            gscale[k] += gJM[3 * r + k] * E.Jw[3 * r + j] * sp.R[3 * j + k];
          }
      for (int r = 0; r < 2; ++r)  // Jw[r][j] = (P[r][j] - m2[r] P[2][j]) / w
        for (int j = 0; j < 3; ++j) {
          g2[r] -= gJw[3 * r + j] * Pc[8 + j] / E.w;
          gw -= gJw[3 * r + j] * E.Jw[3 * r + j] / E.w;
        }
      gw -= (g2[0] * E.m2[0] + g2[1] * E.m2[1]) / E.w;
      const Lanes ghom[4] = {g2[0] / E.w, g2[1] / E.w, gw, g[2]};
      for (int j = 0; j < 3; ++j)
        gmean[j] += Pc[j] * ghom[0] + Pc[4 + j] * ghom[1] + Pc[8 + j] * ghom[2] + Pc[12 + j] * ghom[3];
    }
    proj::store_splat_grads(sp, gR, gmean, gscale, 3, n0, nb, om, oq, os);
  }
}

template <typename T>
P3<T> inputs(const Projection& pr, const at::Tensor& Pd) {
  return P3<T>{pr.means.data_ptr<T>(), pr.quats.data_ptr<T>(), pr.scales.data_ptr<T>(), Pd.data_ptr<double>(),
               pr.means.size(0), pr.P.size(0), double(T(pr.near))};
}

}  // namespace

// -> means2d [C*N, 2], depth [C*N], conics [C*N, 3], cov (a, b, c) [C*N, 3]
std::vector<at::Tensor> project3d_forward(const Projection& pr) {
  for (auto* t : {&pr.means, &pr.quats, &pr.scales, &pr.P}) proj::check(*t);
  const int64_t N = pr.means.size(0), C = pr.P.size(0);
  auto o = pr.means.options();
  auto m2 = at::empty({C * N, 2}, o), dep = at::empty({C * N}, o), con = at::empty({C * N, 3}, o),
       cov = at::empty({C * N, 3}, o);
  auto Pd = pr.P.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(pr.means.scalar_type(), "project3d_forward", [&] {
    const P3<scalar_t> a = inputs<scalar_t>(pr, Pd);
    parallel_range(N, proj::kGrain, [&](int64_t b, int64_t e, int) {
      forward_range(a, b, e, m2.data_ptr<scalar_t>(), dep.data_ptr<scalar_t>(), con.data_ptr<scalar_t>(),
                    cov.data_ptr<scalar_t>());
    });
  });
  return {m2, dep, con, cov};
}

// -> g_means [N,3], g_quats [N,4], g_scales [N,3], g_shift [C*N, 2] (= g_means2d)
std::vector<at::Tensor> project3d_backward(const Projection& pr, const at::Tensor& gm2, const at::Tensor& gdep,
                                           const at::Tensor& gcon) {
  for (auto* t : {&pr.means, &pr.quats, &pr.scales, &pr.P, &gm2, &gdep, &gcon}) proj::check(*t);
  auto gm = at::empty_like(pr.means), gq = at::empty_like(pr.quats), gs = at::empty_like(pr.scales);
  auto Pd = pr.P.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(pr.means.scalar_type(), "project3d_backward", [&] {
    const P3<scalar_t> a = inputs<scalar_t>(pr, Pd);
    parallel_range(a.N, proj::kGrain, [&](int64_t b, int64_t e, int) {
      backward_range(a, gm2.data_ptr<scalar_t>(), gdep.data_ptr<scalar_t>(), gcon.data_ptr<scalar_t>(), b, e,
                     gm.data_ptr<scalar_t>(), gq.data_ptr<scalar_t>(), gs.data_ptr<scalar_t>());
    });
  });
  return {gm, gq, gs, gm2.clone()};
}

}  // namespace arcsem
