// Shared by the fused compositing kernels: the official thresholds, the tile grid, a vectorisable exp, the
// per-entry reduction of per-pair gradients, output finishing.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <type_traits>
#include <vector>

#include "pool.h"

namespace arcsem {

constexpr double kMinAlpha = 1.0 / 255.0;  // skip fainter splats
constexpr double kMaxAlpha = 0.99;         // clamp
constexpr double kMinT = 1e-4;             // stop before the transmittance would fall below this

struct Grid {  // tiles of ct = c * tiles() + t
  int64_t C, H, W, tile, tx, ty;
  int64_t tiles() const { return tx * ty; }
  int64_t x0(int64_t ct) const { return (ct % tiles() % tx) * tile; }
  int64_t y0(int64_t ct) const { return (ct % tiles() / tx) * tile; }
  int64_t nx(int64_t ct) const { return std::min(tile, W - x0(ct)); }
  int64_t ny(int64_t ct) const { return std::min(tile, H - y0(ct)); }
};

inline Grid make_grid(int64_t C, int64_t H, int64_t W, int64_t tile) {
  return Grid{C, H, W, tile, (W + tile - 1) / tile, (H + tile - 1) / tile};
}

constexpr int64_t kGatherBatch = 64;  // pairs a forward pass gathers at once (as far as its tile's pixels go on)
constexpr int kLanes = 16;  // pixels of a tile row evaluated together (one AVX-512 / two AVX2 registers of float)

// The lane blocks of a pair's columns [x0, x1] on a tile row: each kLanes-aligned block they overlap, whole where
// both its halves hold columns of the pair, else only the half that does, and so on down to Min lanes (a narrow
// splat is evaluated on fewer pixels; the median 2DGS pair's box is 13 pixels on a trained model). The forward
// passes go down to 4 lanes, the backward passes to 8 (their 4-lane loops ran 2.6x slower: measured).
// f(lanes, first column), lanes a std::integral_constant.
template <int NL, int Min, class F>
inline void lane_block(int c, int x0, int x1, const F& f) {
  if constexpr (NL > Min) {
    constexpr int half = NL / 2;
    const bool lo = c + half > x0, hi = c + half <= x1;
    if (!(lo && hi)) return lane_block<half, Min>(lo ? c : c + half, x0, x1, f);
  }
  f(std::integral_constant<int, NL>(), c);
}

template <int Min, class F>
inline void for_lane_blocks(int x0, int x1, const F& f) {
  for (int c = x0 / kLanes * kLanes; c <= x1; c += kLanes) lane_block<kLanes, Min>(c, x0, x1, f);
}

// exp(x) for x <= 0, vectorisable (no libm call inside `omp simd` loops). float: Cody-Waite reduction and the
// degree-6 polynomial of Cephes' expf (about 2 ulp; 0 below -87); double: std::exp (the parity tests' type).
inline float vexp(float x) {
  x = std::min(std::max(x, -87.0f), 0.0f);
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  float r = x - n * 0.693359375f;
  r = r + n * 2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const int32_t bits = (int32_t(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}
inline double vexp(double x) { return std::exp(std::min(x, 0.0)); }

// Per-pair gradient rows of a backward pass: [P, D] values, written only for the pairs a tile composited (a
// tile's pairs after its last composited one, or after the forward stopped, are never read: used[p] = 0). Not
// zero-filled on allocation (a serial memset of tens of MB a view).
template <typename T>
struct PairRows {
  int64_t D;
  std::unique_ptr<T[]> rows;
  std::unique_ptr<uint8_t[]> used;
  PairRows(int64_t P, int64_t D) : D(D), rows(new T[size_t(P * D)]), used(new uint8_t[size_t(P)]) {}
  T* tile(int64_t start) { return rows.get() + start * D; }
  // a tile's n pairs from start, of which the first k (its pairs up to the last composited one) have rows
  void mark(int64_t start, int64_t n, int64_t k) {
    std::memset(used.get() + start, 1, size_t(k));
    std::memset(used.get() + start + k, 0, size_t(n - k));
  }
};

// The rows (D values each: pr.D) summed per entry in the fixed order of the tile lists' pair_of (so the result
// does not depend on threads or timing), in double, unused pairs adding nothing: f(s, sum) for every entry s, in
// parallel. The rows are read in entry order, scattered in memory: a row and its flag are asked for 8 pairs ahead.
template <int D, typename T, class F>
inline void reduce_pairs(int64_t M, const PairRows<T>& pr, const int64_t* entry_offsets, const int64_t* pair_of,
                         const F& f) {
  TORCH_CHECK(pr.D == D, "reduce_pairs: rows of ", pr.D, " values, expected ", D);
  constexpr int64_t ahead = 8;
  const T* rows = pr.rows.get();
  const uint8_t* used = pr.used.get();
  parallel_range(M, 2048, [&](int64_t b, int64_t e, int) {
    const int64_t k1 = entry_offsets[e];
    double acc[D];
    for (int64_t s = b; s < e; ++s) {
      std::fill(acc, acc + D, 0.0);
      for (int64_t k = entry_offsets[s]; k < entry_offsets[s + 1]; ++k) {
        if (k + ahead < k1) {
          const int64_t q = pair_of[k + ahead];
          __builtin_prefetch(used + q);
          __builtin_prefetch(rows + q * D);
          if constexpr (D > 1) __builtin_prefetch(rows + q * D + D - 1);
        }
        const int64_t p = pair_of[k];
        if (!used[p]) continue;
        const T* r = rows + p * D;
        for (int d = 0; d < D; ++d) acc[d] += double(r[d]);
      }
      f(s, static_cast<const double*>(acc));
    }
  });
}

inline void cross(const double* x, const double* y, double* out) {
  out[0] = x[1] * y[2] - x[2] * y[1];
  out[1] = x[2] * y[0] - x[0] * y[2];
  out[2] = x[0] * y[1] - x[1] * y[0];
}

// [M, K1] and [M, K2] -> [M, K1 + K2] (a plain loop: no fork/join of an ATen op)
template <typename T>
inline void concat_rows(const T* a, int64_t K1, const T* b, int64_t K2, int64_t M, T* out) {
  for (int64_t s = 0; s < M; ++s) {
    std::copy(a + s * K1, a + (s + 1) * K1, out + s * (K1 + K2));
    std::copy(b + s * K2, b + (s + 1) * K2, out + s * (K1 + K2) + K1);
  }
}

}  // namespace arcsem

namespace arcsem {

// columns [k0, k0 + n) of a contiguous [M, K] tensor as a new contiguous tensor (a plain loop)
inline at::Tensor split_cols(const at::Tensor& x, int64_t k0, int64_t n) {
  const int64_t M = x.size(0), K = x.size(1);
  auto out = at::empty({M, n}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "split_cols", [&] {
    const scalar_t* src = x.data_ptr<scalar_t>();
    scalar_t* dst = out.data_ptr<scalar_t>();
    for (int64_t s = 0; s < M; ++s) std::copy(src + s * K + k0, src + s * K + k0 + n, dst + s * n);
  });
  return out;
}
inline at::Tensor split_cols(const at::Tensor& x, int64_t n) { return split_cols(x, 0, n); }

// Final per-pixel outputs, in T arithmetic as the PyTorch path: rgb = f[0:3] + (1 - alpha) bg (bg may be
// null), extra = f[3:K], depth = where(alpha > 0, wz / max(alpha, 1e-30), 0) with wz at wz[p * wz_stride].
template <typename T>
inline void finish_outputs(int64_t P, int64_t K, const T* f, const T* alpha, const T* wz, int64_t wz_stride,
                           const T* bg, T* rgb, T* extra, T* depth) {
  for (int64_t p = 0; p < P; ++p) {
    const T a = alpha[p];
    for (int k = 0; k < 3; ++k) rgb[3 * p + k] = bg ? f[p * K + k] + (T(1) - a) * bg[k] : f[p * K + k];
    for (int64_t k = 3; k < K; ++k) extra[p * (K - 3) + k - 3] = f[p * K + k];
    depth[p] = a > T(0) ? wz[p * wz_stride] / std::max(a, T(1e-30)) : T(0);
  }
}

// Gradients of finish_outputs back to (f, alpha, wz); null output gradients are zero. g_f [P, K] gets
// g_rgb and g_extra, g_alpha and g_wz (at g_wz[p * g_wz_stride], may alias g_f) are overwritten.
template <typename T>
inline void finish_backward(int64_t P, int64_t K, const T* alpha, const T* wz, int64_t wz_stride, const T* bg,
                            const T* g_rgb, const T* g_extra, const T* g_alpha_in, const T* g_depth, T* g_f,
                            T* g_alpha, T* g_wz, int64_t g_wz_stride) {
  for (int64_t p = 0; p < P; ++p) {
    const T a = alpha[p];
    T ga = g_alpha_in ? g_alpha_in[p] : T(0);
    for (int k = 0; k < 3; ++k) {
      const T g = g_rgb ? g_rgb[3 * p + k] : T(0);
      g_f[p * K + k] = g;
      if (bg) ga -= g * bg[k];
    }
    for (int64_t k = 3; k < K; ++k) g_f[p * K + k] = g_extra ? g_extra[p * (K - 3) + k - 3] : T(0);
    T gw = 0;
    if (g_depth && a > T(0)) {
      const T ac = std::max(a, T(1e-30)), gd = g_depth[p];
      gw = gd / ac;
      if (a >= T(1e-30)) ga -= gd * wz[p * wz_stride] / (ac * ac);
    }
    g_alpha[p] = ga;
    g_wz[p * g_wz_stride] = gw;
  }
}

}  // namespace arcsem

namespace arcsem {

// a gradient tensor's data, or null when autograd passed none (the output was not used)
template <typename T>
inline const T* grad_or_null(const at::Tensor& g) { return g.defined() && g.numel() ? g.data_ptr<T>() : nullptr; }

inline void check_cpu(const at::Tensor& t, const char* what) {
  TORCH_CHECK(t.defined() && t.is_contiguous() && t.device().is_cpu(), what, " must be a contiguous CPU tensor");
}

// A per-pair work list kept from the forward pass for the backward pass: P records of type R as a byte tensor.
template <typename R>
inline at::Tensor pair_storage(int64_t P, const at::Tensor& like) {
  return at::empty({P * int64_t(sizeof(R))}, like.options().dtype(at::kByte));
}
template <typename R>
inline R* pair_records(const at::Tensor& bytes) { return reinterpret_cast<R*>(bytes.data_ptr<uint8_t>()); }

// Starts a tile of nx x ny pixels in a compositing state st (Tile2 / Tile3: stride, row_live, live, tr): every
// pixel live with transmittance 1. Returns the number of live pixels.
template <template <typename> class St, typename T>
inline int start_tile(St<T>& st, int nx, int ny) {
  const int S = st.stride;
  for (int y = 0; y < ny; ++y) {
    st.row_live[y] = nx;
    std::fill(st.live.begin() + y * S, st.live.begin() + y * S + nx, T(1));
  }
  std::fill(st.tr.begin(), st.tr.end(), T(1));
  return nx * ny;
}

}  // namespace arcsem
