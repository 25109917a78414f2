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

}  // namespace arcsem
