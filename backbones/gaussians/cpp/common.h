// Shared by the fused compositing kernels: the official thresholds, the tile grid, row bucketing,
// dynamic tile scheduling.
#pragma once
#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <vector>

namespace arcsem {

constexpr double kMinAlpha = 1.0 / 255.0;  // skip fainter splats
constexpr double kMaxAlpha = 0.99;         // clamp
constexpr double kMinT = 1e-4;             // stop before the transmittance would fall below this

struct Grid {
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

// A pair in a row bucket: local index j in the tile and its pixel columns [x0, x1] (scanned per pixel, so
// kept small and contiguous: the pair's data is read only when the pixel lies inside its box).
struct RowEntry {
  int32_t j, x0, x1;
};

// Per-tile bucketing: local pairs j in [0, n) with inclusive pixel box box(j) = {x0, x1, y0, y1}.
template <class Box>
inline void bucket_rows_local(int64_t n, const Box& box, int64_t y0, int64_t ny, std::vector<std::vector<RowEntry>>& rows) {
  rows.resize(ny);
  for (auto& r : rows) r.clear();
  for (int64_t j = 0; j < n; ++j) {
    const int64_t* b = box(j);
    const int64_t lo = std::max(b[2], y0), hi = std::min(b[3], y0 + ny - 1);
    for (int64_t y = lo; y <= hi; ++y) rows[y - y0].push_back(RowEntry{int32_t(j), int32_t(b[0]), int32_t(b[1])});
  }
}

// Entries of a row up to local pair index jmax (inclusive), for the back-to-front backward pass.
inline std::vector<RowEntry>::const_iterator row_end(const std::vector<RowEntry>& row, int64_t jmax) {
  return std::upper_bound(row.begin(), row.end(), jmax, [](int64_t k, const RowEntry& e) { return k < e.j; });
}

// Runs f(t) for t in [0, n), handing tiles one at a time to whichever thread is running: a static split
// stalls on a shared machine whenever one thread is descheduled. f may use at::get_thread_num().
template <class F>
inline void for_each_tile(int64_t n, const F& f) {
  std::atomic<int64_t> next{0};
  const int64_t nt = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n));
  at::parallel_for(0, nt, 1, [&](int64_t, int64_t) {
    for (int64_t t = next++; t < n; t = next++) f(t);
  });
}

// g[0, D) = splat s's gradient row summed over the per-thread buffers (threads that got no tile left
// theirs empty). Buffers are [M, D] row-major doubles.
inline void sum_thread_rows(const std::vector<std::vector<double>>& bufs, int64_t s, int64_t D, double* g) {
  std::fill(g, g + D, 0.0);
  for (const auto& buf : bufs)
    if (!buf.empty())
      for (int64_t k = 0; k < D; ++k) g[k] += buf[s * D + k];
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

#include <torch/extension.h>

namespace arcsem {

// columns [k0, k0 + n) of a contiguous [M, K] tensor as a new contiguous tensor (a plain loop)
inline torch::Tensor split_cols(const torch::Tensor& x, int64_t k0, int64_t n) {
  const int64_t M = x.size(0), K = x.size(1);
  auto out = torch::empty({M, n}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "split_cols", [&] {
    const scalar_t* src = x.data_ptr<scalar_t>();
    scalar_t* dst = out.data_ptr<scalar_t>();
    for (int64_t s = 0; s < M; ++s) std::copy(src + s * K + k0, src + s * K + k0 + n, dst + s * n);
  });
  return out;
}
inline torch::Tensor split_cols(const torch::Tensor& x, int64_t n) { return split_cols(x, 0, n); }

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
