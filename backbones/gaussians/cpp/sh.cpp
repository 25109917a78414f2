// Spherical-harmonics colours of every (camera, splat), forward and backward, fused (backbones/gaussians/sh.py is the
// reference: the same basis, normalisation and clamp).
//   dir = normalize(mean - centre) (pinhole) or the camera's forward axis (orthographic); F.normalize's eps 1e-12
//   rgb = max(sum_k sh[k] Y_k(dir) + 0.5, 0) over the first (degree + 1)^2 coefficients
//   with ACT (arcsem/act.py ACT.apply is the reference): clamp(w[c] rgb + b[c], 0, 1) per camera c and channel
// Parallel over splats (each handles its cameras), so sums over cameras have a fixed order; blocks of 16 splats, one
// a lane of the vectorised loops (the coefficients transposed per block).
#include <algorithm>
#include <cmath>
#include <type_traits>

#include "api.h"
#include "pool.h"

namespace arcsem {
namespace {

constexpr double C0 = 0.28209479177387814, C1 = 0.4886025119029199;
constexpr double C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                          0.5462742152960396};
constexpr double C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                          -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// Y_k(d) for k < (Deg + 1)^2 at Y[k * S] and, with Grad, dY_k / d(x, y, z) at dY[(3 k + a) * S] (S: the stride
// of a block's lanes, 1 for one splat)
template <int Deg, bool Grad, int S, typename T>
inline void basis(T x, T y, T z, T* Y, T* dY) {
  auto set = [&](int k, T v) { Y[k * S] = v; };
  auto setd = [&](int k, T dx, T dy, T dz) {
    if constexpr (Grad) {
      dY[(3 * k) * S] = dx;
      dY[(3 * k + 1) * S] = dy;
      dY[(3 * k + 2) * S] = dz;
    }
  };
  set(0, T(C0));
  setd(0, 0, 0, 0);
  if constexpr (Deg >= 1) {
    set(1, T(-C1) * y); set(2, T(C1) * z); set(3, T(-C1) * x);
    setd(1, 0, T(-C1), 0); setd(2, 0, 0, T(C1)); setd(3, T(-C1), 0, 0);
  }
  if constexpr (Deg >= 2) {
    const T xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
    set(4, T(C2[0]) * xy); set(5, T(C2[1]) * yz); set(6, T(C2[2]) * (2 * zz - xx - yy)); set(7, T(C2[3]) * xz);
    set(8, T(C2[4]) * (xx - yy));
    setd(4, T(C2[0]) * y, T(C2[0]) * x, 0);
    setd(5, 0, T(C2[1]) * z, T(C2[1]) * y);
    setd(6, T(C2[2]) * -2 * x, T(C2[2]) * -2 * y, T(C2[2]) * 4 * z);
    setd(7, T(C2[3]) * z, 0, T(C2[3]) * x);
    setd(8, T(C2[4]) * 2 * x, T(C2[4]) * -2 * y, 0);
    if constexpr (Deg >= 3) {
      set(9, T(C3[0]) * y * (3 * xx - yy));
      set(10, T(C3[1]) * xy * z);
      set(11, T(C3[2]) * y * (4 * zz - xx - yy));
      set(12, T(C3[3]) * z * (2 * zz - 3 * xx - 3 * yy));
      set(13, T(C3[4]) * x * (4 * zz - xx - yy));
      set(14, T(C3[5]) * z * (xx - yy));
      set(15, T(C3[6]) * x * (xx - 3 * yy));
      setd(9, T(C3[0]) * 6 * xy, T(C3[0]) * (3 * xx - 3 * yy), 0);
      setd(10, T(C3[1]) * yz, T(C3[1]) * xz, T(C3[1]) * xy);
      setd(11, T(C3[2]) * -2 * xy, T(C3[2]) * (4 * zz - xx - 3 * yy), T(C3[2]) * 8 * yz);
      setd(12, T(C3[3]) * -6 * xz, T(C3[3]) * -6 * yz, T(C3[3]) * (6 * zz - 3 * xx - 3 * yy));
      setd(13, T(C3[4]) * (4 * zz - 3 * xx - yy), T(C3[4]) * -2 * xy, T(C3[4]) * 8 * xz);
      setd(14, T(C3[5]) * 2 * xz, T(C3[5]) * -2 * yz, T(C3[5]) * (xx - yy));
      setd(15, T(C3[6]) * (3 * xx - 3 * yy), T(C3[6]) * -6 * xy, 0);
    }
  }
}

constexpr int64_t kGrain = 1024;  // splats per chunk
constexpr int L = 16;             // splats of a block, one a lane: every lane loop below is `omp simd` over them

template <typename T>
struct Sh {  // the inputs (means [N, 3], sh_dc [N, 1, 3], sh_rest [N, R, 3], origins [C, 3], ACT [C, 3] or null)
  const T *m, *dc, *rest, *o, *aw, *ab;
  int64_t N, C, R;
  bool ortho;
};

// A block of L splats from n0 (nb of them real; the other lanes repeat the last one and are not written):
// coefficients transposed to [K][3][L], then per camera the viewing directions [3][L] (F.normalize: v / max(|v|,
// 1e-12); |v| in len) and the basis [K][L] (and its gradient [3K][L]) of every lane.
template <int K, typename T>
struct Block {
  alignas(64) T sh[K][3][L];
  alignas(64) T d[3][L], len[L], Y[K][L], dY[3 * K][L], x[3][L];  // x: the colour before the clamp
  int64_t n[L];
  void load(const Sh<T>& a, int64_t n0, int nb) {
    for (int i = 0; i < L; ++i) n[i] = n0 + std::min(i, nb - 1);
    for (int i = 0; i < L; ++i)
      for (int ch = 0; ch < 3; ++ch) {
        sh[0][ch][i] = a.dc[3 * n[i] + ch];
        for (int k = 1; k < K; ++k) sh[k][ch][i] = a.rest[(n[i] * a.R + k - 1) * 3 + ch];
      }
  }
  template <int Deg, bool Grad>
  void view(const Sh<T>& a, int64_t c) {  // directions, basis and colours before the clamp, from camera c
    const T* o = a.o + 3 * c;
#pragma omp simd
    for (int i = 0; i < L; ++i) {
      T v[3];
      for (int ax = 0; ax < 3; ++ax) {  // (both read: a select, not a branch)
        const T rel = a.m[3 * n[i] + ax] - o[ax];
        v[ax] = a.ortho ? o[ax] : rel;
      }
      len[i] = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      const T den = len[i] > T(1e-12) ? len[i] : T(1e-12);
      for (int ax = 0; ax < 3; ++ax) d[ax][i] = v[ax] / den;
    }
#pragma omp simd
    for (int i = 0; i < L; ++i) basis<Deg, Grad, L>(d[0][i], d[1][i], d[2][i], &Y[0][i], &dY[0][i]);
#pragma omp simd
    for (int i = 0; i < L; ++i)
      for (int ch = 0; ch < 3; ++ch) {
        T s = T(0);
        for (int k = 0; k < K; ++k) s += Y[k][i] * sh[k][ch][i];
        x[ch][i] = s + T(0.5);
      }
  }
};

template <int Deg, typename T>
void forward_range(const Sh<T>& a, int64_t b, int64_t e, T* rgb) {
  constexpr int K = (Deg + 1) * (Deg + 1);
  Block<K, T> bl;
  for (int64_t n0 = b; n0 < e; n0 += L) {
    const int nb = int(std::min<int64_t>(L, e - n0));
    bl.load(a, n0, nb);
    for (int64_t c = 0; c < a.C; ++c) {
      bl.template view<Deg, false>(a, c);
      for (int i = 0; i < nb; ++i)
        for (int ch = 0; ch < 3; ++ch) {
          const T v = std::max(bl.x[ch][i], T(0));
          rgb[(c * a.N + n0 + i) * 3 + ch] = a.aw ? std::min(std::max(a.aw[3 * c + ch] * v + a.ab[3 * c + ch], T(0)), T(1)) : v;
        }
    }
  }
}

// gradients of the splats [b, e): means (through the viewing direction: Dir), sh_dc, sh_rest (0 above the degree);
// with ACT the range's sums for its w and b into gact [C][6] (w: 0..2, b: 3..5)
template <int Deg, bool Dir, typename T>
void backward_range(const Sh<T>& a, const T* g, int64_t b, int64_t e, T* om, T* odc, T* orest, double* gact) {
  constexpr int K = (Deg + 1) * (Deg + 1);
  Block<K, T> bl;
  alignas(64) T gsh[K][3][L], gv[3][L], gc[3][L];
  for (int64_t n0 = b; n0 < e; n0 += L) {
    const int nb = int(std::min<int64_t>(L, e - n0));
    bl.load(a, n0, nb);
    std::fill(&gsh[0][0][0], &gsh[0][0][0] + K * 3 * L, T(0));
    std::fill(&gv[0][0], &gv[0][0] + 3 * L, T(0));
    for (int64_t c = 0; c < a.C; ++c) {
      bl.template view<Deg, Dir>(a, c);
      for (int i = 0; i < L; ++i)  // clamp_min(x, 0) passes the gradient where x >= 0 (clamp: where in [0, 1])
        for (int ch = 0; ch < 3; ++ch) {
          T gi = g[(c * a.N + bl.n[i]) * 3 + ch];
          if (a.aw) {
            const T v = std::max(bl.x[ch][i], T(0)), w = a.aw[3 * c + ch], y = w * v + a.ab[3 * c + ch];
            gi = (y >= T(0)) & (y <= T(1)) ? gi : T(0);
            if (i < nb) {
              gact[6 * c + ch] += double(gi * v);
              gact[6 * c + 3 + ch] += double(gi);
            }
            gi *= w;
          }
          gc[ch][i] = bl.x[ch][i] >= T(0) ? gi : T(0);
        }
#pragma omp simd
      for (int i = 0; i < L; ++i)
        for (int k = 0; k < K; ++k)
          for (int ch = 0; ch < 3; ++ch) gsh[k][ch][i] += bl.Y[k][i] * gc[ch][i];
      if constexpr (Dir) {
#pragma omp simd
        for (int i = 0; i < L; ++i) {
          T gd0 = 0, gd1 = 0, gd2 = 0;
#pragma GCC unroll 16
          for (int k = 1; k < K; ++k) {
            const T gb = bl.sh[k][0][i] * gc[0][i] + bl.sh[k][1][i] * gc[1][i] + bl.sh[k][2][i] * gc[2][i];
            gd0 += gb * bl.dY[3 * k][i];
            gd1 += gb * bl.dY[3 * k + 1][i];
            gd2 += gb * bl.dY[3 * k + 2][i];
          }
          const T gd[3] = {gd0, gd1, gd2}, len = bl.len[i];
          const T dot = len > T(1e-12) ? gd0 * bl.d[0][i] + gd1 * bl.d[1][i] + gd2 * bl.d[2][i] : T(0);
          const T den = len > T(1e-12) ? len : T(1e-12);  // d = v / max(|v|, eps): dd/dv = (I - d d^T) / |v| above eps
          for (int ax = 0; ax < 3; ++ax) gv[ax][i] += (gd[ax] - bl.d[ax][i] * dot) / den;
        }
      }
    }
    for (int i = 0; i < nb; ++i) {
      const int64_t n = n0 + i;
      for (int ch = 0; ch < 3; ++ch) odc[3 * n + ch] = gsh[0][ch][i];
      for (int k = 1; k < K; ++k)
        for (int ch = 0; ch < 3; ++ch) orest[(n * a.R + k - 1) * 3 + ch] = gsh[k][ch][i];
      std::fill(orest + (n * a.R + K - 1) * 3, orest + (n + 1) * a.R * 3, T(0));  // coefficients above the degree
      for (int ax = 0; ax < 3; ++ax) om[3 * n + ax] = gv[ax][i];
    }
  }
}

// f(std::integral_constant<int, degree>) for degree 0..3
template <class F>
inline void with_degree(int64_t degree, const F& f) {
  switch (degree) {
    case 0: return f(std::integral_constant<int, 0>());
    case 1: return f(std::integral_constant<int, 1>());
    case 2: return f(std::integral_constant<int, 2>());
    default: return f(std::integral_constant<int, 3>());
  }
}

template <typename T>
Sh<T> inputs(const ShColors& a) {
  const bool act = a.act_w.defined() && a.act_w.numel() > 0;
  if (act) {
    for (auto* t : {&a.act_w, &a.act_b})
      TORCH_CHECK(t->is_contiguous() && t->dim() == 2 && t->size(0) == a.origins.size(0) && t->size(1) == 3 &&
                      t->scalar_type() == a.means.scalar_type(), "sh_colors: ACT w, b must be contiguous [C, 3] of the means' type");
  }
  return Sh<T>{a.means.data_ptr<T>(), a.sh_dc.data_ptr<T>(), a.sh_rest.data_ptr<T>(), a.origins.data_ptr<T>(),
               act ? a.act_w.data_ptr<T>() : nullptr, act ? a.act_b.data_ptr<T>() : nullptr,
               a.means.size(0), a.origins.size(0), a.sh_rest.size(1), a.ortho};
}

}  // namespace

at::Tensor sh_colors_forward(const ShColors& a) {
  for (auto* t : {&a.means, &a.sh_dc, &a.sh_rest, &a.origins}) TORCH_CHECK(t->is_contiguous(), "sh_colors: inputs must be contiguous");
  const int64_t N = a.means.size(0), C = a.origins.size(0), K = (a.degree + 1) * (a.degree + 1), R = a.sh_rest.size(1);
  TORCH_CHECK(a.degree >= 0 && a.degree <= 3 && K - 1 <= R, "sh_colors: degree ", a.degree, " needs ", K - 1, " rest coefficients");
  auto out = at::empty({C, N, 3}, a.means.options());
  AT_DISPATCH_FLOATING_TYPES(a.means.scalar_type(), "sh_colors_forward", [&] {
    const Sh<scalar_t> in = inputs<scalar_t>(a);
    scalar_t* rgb = out.data_ptr<scalar_t>();
    with_degree(a.degree, [&](auto deg) {
      parallel_range(N, kGrain, [&](int64_t b, int64_t e, int) { forward_range<decltype(deg)::value>(in, b, e, rgb); });
    });
  });
  return out;
}

std::vector<at::Tensor> sh_colors_backward(const ShColors& a, const at::Tensor& g_colors) {
  // every entry is written below (unused rest coefficients get 0): no zero fill of [N, 15, 3] first
  auto gm = at::empty_like(a.means), gdc = at::empty_like(a.sh_dc), grest = at::empty_like(a.sh_rest);
  at::Tensor gw, gb;
  auto g_in = g_colors.contiguous();
  AT_DISPATCH_FLOATING_TYPES(a.means.scalar_type(), "sh_colors_backward", [&] {
    using T = scalar_t;
    const Sh<T> in = inputs<T>(a);
    const T* g = g_in.data_ptr<T>();
    T *om = gm.data_ptr<T>(), *odc = gdc.data_ptr<T>(), *orest = grest.data_ptr<T>();
    // ACT: each chunk's sums apart, then added in chunk order (the result does not depend on threads or timing)
    const int64_t chunks = (in.N + kGrain - 1) / kGrain;
    std::vector<double> part(in.aw ? size_t(chunks * in.C * 6) : 0, 0.0);
    with_degree(a.degree, [&](auto deg) {
      constexpr int Deg = decltype(deg)::value;
      parallel_range(in.N, kGrain, [&](int64_t b, int64_t e, int) {
        double* gact = in.aw ? part.data() + b / kGrain * in.C * 6 : nullptr;
        if (!a.ortho && Deg > 0) backward_range<Deg, true>(in, g, b, e, om, odc, orest, gact);
        else backward_range<Deg, false>(in, g, b, e, om, odc, orest, gact);
      });
    });
    if (in.aw) {
      gw = at::empty_like(a.act_w);
      gb = at::empty_like(a.act_b);
      T *ow = gw.data_ptr<T>(), *ob = gb.data_ptr<T>();
      for (int64_t k = 0; k < in.C * 3; ++k) {
        double sw = 0, sb = 0;
        for (int64_t ch = 0; ch < chunks; ++ch) {
          sw += part[size_t((ch * in.C + k / 3) * 6 + k % 3)];
          sb += part[size_t((ch * in.C + k / 3) * 6 + 3 + k % 3)];
        }
        ow[k] = T(sw);
        ob[k] = T(sb);
      }
    }
  });
  return {gm, gdc, grest, gw.defined() ? gw : at::Tensor(), gb.defined() ? gb : at::Tensor()};
}

}  // namespace arcsem
