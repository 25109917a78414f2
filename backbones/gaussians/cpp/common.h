// Shared by the fused compositing kernels: the official thresholds, the tile grid, row bucketing.
#pragma once
#include <algorithm>
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

// Pairs [start, end) of one tile bucketed by pixel row, depth order kept: a pixel visits only the
// pairs whose pixel box (x0, x1, y0, y1; outside it alpha < 1/255) covers its row.
inline void bucket_rows(const int64_t* ids, const int64_t* box, int64_t start, int64_t end, int64_t y0, int64_t ny,
                        std::vector<std::vector<int64_t>>& rows) {
  rows.resize(ny);
  for (auto& r : rows) r.clear();
  for (int64_t i = start; i < end; ++i) {
    const int64_t* b = box + 4 * ids[i];
    const int64_t lo = std::max(b[2], y0), hi = std::min(b[3], y0 + ny - 1);
    for (int64_t y = lo; y <= hi; ++y) rows[y - y0].push_back(i);
  }
}

inline bool outside_x(const int64_t* box, int64_t s, int64_t x) { return x < box[4 * s] || x > box[4 * s + 1]; }

}  // namespace arcsem
