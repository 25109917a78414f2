// Fused per-splat projection of 2DGS surfels, forward and backward (conventions: project.h).
//
// A port of gs2d/render.py splat_homographies + camera_facing_normals + the screen-position shift, on kL surfels at
// once (proj::Lanes). The screen-position leaf enters as a shift of value zero (raster.screen_position_leaf), so the
// forward ignores it and the backward returns its gradient.
#include <vector>

#include "pool.h"
#include "project.h"

namespace arcsem {
namespace {

using proj::kL;
using proj::Lanes;
using proj::splat;
using proj::stored;
using proj::Splat;

template <typename T>
struct P2 {  // a projection's inputs: means [N, 3], quats [N, 4], scales [N, 2], P [C, 16], view [C, 3] (double)
  const T *m, *q, *sc;
  const double *P, *view;
  int64_t N, C;
  bool ortho;
};

template <typename T>
P2<T> inputs(const Projection& pr, const at::Tensor& Pd, const at::Tensor& Vd) {
  return P2<T>{pr.means.data_ptr<T>(), pr.quats.data_ptr<T>(), pr.scales.data_ptr<T>(), Pd.data_ptr<double>(),
               Vd.data_ptr<double>(), pr.means.size(0), pr.P.size(0), pr.ortho};
}

// homography rows Tu, Tv, Tw, Tz (12 values): H[i][k] = sum_j P[i][j] S[j][k], S = [R0 s0, R1 s1, (m, 1)]
inline void homography(const Splat& sp, const double* P, Lanes Hm[12]) {
  for (int i = 0; i < 4; ++i) {
    const double* p = P + 4 * i;
    Hm[3 * i] = (p[0] * sp.R[0] + p[1] * sp.R[3] + p[2] * sp.R[6]) * sp.s[0];
    Hm[3 * i + 1] = (p[0] * sp.R[1] + p[1] * sp.R[4] + p[2] * sp.R[7]) * sp.s[1];
    Hm[3 * i + 2] = p[0] * sp.m[0] + p[1] * sp.m[1] + p[2] * sp.m[2] + p[3];
  }
}

// camera_facing_normals: -1 or +1 for column 2 of R (view: the camera's forward axis or centre)
inline Lanes facing(const Splat& sp, const double* view, bool ortho) {
  Lanes v[3];
  for (int j = 0; j < 3; ++j) v[j] = ortho ? splat(view[j]) : sp.m[j] - view[j];
  return sp.R[2] * v[0] + sp.R[5] * v[1] + sp.R[8] * v[2] > 0 ? splat(-1.0) : splat(1.0);
}

template <typename T>
void forward_range(const P2<T>& a, int64_t b, int64_t e, T* H, T* Z, T* ct, T* nr) {
  for (int64_t n0 = b; n0 < e; n0 += kL) {
    const int nb = int(std::min<int64_t>(kL, e - n0));
    const Splat sp = proj::load_splats(a.m, a.q, a.sc, 2, n0, nb);
    for (int64_t c = 0; c < a.C; ++c) {
      Lanes h[12];
      homography(sp, a.P + 16 * c, h);
      const Lanes cx = stored<T>(h[2]) / stored<T>(h[8]), cy = stored<T>(h[5]) / stored<T>(h[8]);  // as the reference
      const Lanes sg = facing(sp, a.view + 3 * c, a.ortho);
      for (int i = 0; i < nb; ++i) {
        const int64_t s = c * a.N + n0 + i;
        for (int j = 0; j < 9; ++j) H[9 * s + j] = T(h[j][i]);
        for (int j = 0; j < 3; ++j) Z[3 * s + j] = T(h[9 + j][i]);
        ct[2 * s] = T(cx[i]);
        ct[2 * s + 1] = T(cy[i]);
        for (int j = 0; j < 3; ++j) nr[3 * s + j] = T(sg[i] * sp.R[3 * j + 2][i]);
      }
    }
  }
}

// the gradients of surfels [b, e) from those of H, Dz, the centres and normals; and of the screen-position shift
template <typename T>
void backward_range(const P2<T>& a, const T* GH, const T* GZ, const T* GC, const T* GN, int64_t b, int64_t e, T* om,
                    T* oq, T* os, T* osh) {
  for (int64_t n0 = b; n0 < e; n0 += kL) {
    const int nb = int(std::min<int64_t>(kL, e - n0));
    const Splat sp = proj::load_splats(a.m, a.q, a.sc, 2, n0, nb);
    Lanes gR[9] = {}, gmean[3] = {}, gscale[2] = {};  // sums over the cameras
    for (int64_t c = 0; c < a.C; ++c) {
      const double* Pc = a.P + 16 * c;
      Lanes g[12], gc[2], gn[3];  // this camera's gradients of H and Dz, the centre, the normal
      for (int i = 0; i < kL; ++i) {
        const int64_t s = c * a.N + n0 + std::min(i, nb - 1);
        for (int j = 0; j < 9; ++j) g[j][i] = GH[9 * s + j];
        for (int j = 0; j < 3; ++j) g[9 + j][i] = GZ[3 * s + j];
        for (int j = 0; j < 2; ++j) gc[j][i] = GC[2 * s + j];
        for (int j = 0; j < 3; ++j) gn[j][i] = GN[3 * s + j];
      }
      Lanes h[12];
      homography(sp, Pc, h);
      // centre = (Tu.z / Tw.z, Tv.z / Tw.z) of the rounded homography
      const Lanes tw = stored<T>(h[8]), cx = stored<T>(h[2]) / tw, cy = stored<T>(h[5]) / tw;
      g[2] += gc[0] / tw;
      g[5] += gc[1] / tw;
      g[8] -= (gc[0] * cx + gc[1] * cy) / tw;
      // Tu += sx Tw, Tv += sy Tw (sx = sy = 0 in value)
      const Lanes gsx = g[0] * h[6] + g[1] * h[7] + g[2] * h[8], gsy = g[3] * h[6] + g[4] * h[7] + g[5] * h[8];
      for (int i = 0; i < nb; ++i) {
        const int64_t s = c * a.N + n0 + i;
        osh[2 * s] = T(gsx[i]);
        osh[2 * s + 1] = T(gsy[i]);
      }
      for (int j = 0; j < 3; ++j) {  // g_S[j][k] = sum_i P[i][j] g[i][k]
        Lanes gS[3];
        for (int k = 0; k < 3; ++k) gS[k] = Pc[j] * g[k] + Pc[4 + j] * g[3 + k] + Pc[8 + j] * g[6 + k] + Pc[12 + j] * g[9 + k];
        gR[3 * j] += gS[0] * sp.s[0];
        gR[3 * j + 1] += gS[1] * sp.s[1];
        gscale[0] += gS[0] * sp.R[3 * j];
        gscale[1] += gS[1] * sp.R[3 * j + 1];
        gmean[j] += gS[2];
      }
      const Lanes sg = facing(sp, a.view + 3 * c, a.ortho);
      for (int j = 0; j < 3; ++j) gR[3 * j + 2] += sg * gn[j];
    }
    proj::store_splat_grads(sp, gR, gmean, gscale, 2, n0, nb, om, oq, os);
  }
}

}  // namespace

// -> H [C*N, 9] (rows Tu, Tv, Tw), Dz [C*N, 3] (row Tz), centre [C*N, 2], normals [C*N, 3]
std::vector<at::Tensor> project2d_forward(const Projection& pr) {
  for (auto* t : {&pr.means, &pr.quats, &pr.scales, &pr.P, &pr.view}) proj::check(*t);
  const int64_t N = pr.means.size(0), C = pr.P.size(0);
  auto o = pr.means.options();
  auto Hm = at::empty({C * N, 9}, o), Dz = at::empty({C * N, 3}, o), ctr = at::empty({C * N, 2}, o), nrm = at::empty({C * N, 3}, o);
  auto Pd = pr.P.to(at::kDouble).contiguous(), Vd = pr.view.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(pr.means.scalar_type(), "project2d_forward", [&] {
    const P2<scalar_t> a = inputs<scalar_t>(pr, Pd, Vd);
    parallel_range(N, proj::kGrain, [&](int64_t b, int64_t e, int) {
      forward_range(a, b, e, Hm.data_ptr<scalar_t>(), Dz.data_ptr<scalar_t>(), ctr.data_ptr<scalar_t>(), nrm.data_ptr<scalar_t>());
    });
  });
  return {Hm, Dz, ctr, nrm};
}

// -> g_means [N,3], g_quats [N,4], g_scales [N,2], g_shift [C*N, 2]
std::vector<at::Tensor> project2d_backward(const Projection& pr, const at::Tensor& gH, const at::Tensor& gDz,
                                              const at::Tensor& gctr, const at::Tensor& gnrm) {
  for (auto* t : {&pr.means, &pr.quats, &pr.scales, &pr.P, &pr.view, &gH, &gDz, &gctr, &gnrm}) proj::check(*t);
  const int64_t N = pr.means.size(0), C = pr.P.size(0);
  auto gm = at::empty_like(pr.means), gq = at::empty_like(pr.quats), gs = at::empty_like(pr.scales);
  auto gsh = at::empty({C * N, 2}, pr.means.options());
  auto Pd = pr.P.to(at::kDouble).contiguous(), Vd = pr.view.to(at::kDouble).contiguous();
  AT_DISPATCH_FLOATING_TYPES(pr.means.scalar_type(), "project2d_backward", [&] {
    const P2<scalar_t> a = inputs<scalar_t>(pr, Pd, Vd);
    parallel_range(N, proj::kGrain, [&](int64_t b, int64_t e, int) {
      backward_range(a, gH.data_ptr<scalar_t>(), gDz.data_ptr<scalar_t>(), gctr.data_ptr<scalar_t>(),
                     gnrm.data_ptr<scalar_t>(), b, e, gm.data_ptr<scalar_t>(), gq.data_ptr<scalar_t>(),
                     gs.data_ptr<scalar_t>(), gsh.data_ptr<scalar_t>());
    });
  });
  return {gm, gq, gs, gsh};
}

}  // namespace arcsem
