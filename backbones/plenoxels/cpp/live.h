// Live masks of a sparse grid for the current density (march.h skips what they mark dead).
//
// cell[i, j, k] (i <= X - 2, ...; uint8): one of the cell's 8 corners is stored with density > 0.
// dist[bx, by, bz] (uint8) over blocks of 2^shift cells per axis: 0 for a block with a live cell, else the
// Chebyshev distance (in blocks) to the nearest live block, capped at kMaxDist + 1: every block closer
// than dist is dead, so a ray may jump over the cube of blocks of radius dist - 1 around it.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

namespace plx {

constexpr int kMaxDist = 15;

inline int64_t num_blocks(int64_t R, int shift) { return ((R - 2) >> shift) + 1; }

// Sparse grids: every positive point marks the <= 8 cells it is a corner of. O(M).
template <typename T>
void cells_from_points(const int64_t* xyz, const T* dens, int64_t M, const int64_t* R, uint8_t* cell) {
  for (int64_t m = 0; m < M; ++m) {
    if (!(dens[m] > 0)) continue;
    const int64_t* p = xyz + 3 * m;
    for (int64_t i = std::max<int64_t>(p[0] - 1, 0); i <= std::min(p[0], R[0] - 2); ++i)
      for (int64_t j = std::max<int64_t>(p[1] - 1, 0); j <= std::min(p[1], R[1] - 2); ++j)
        for (int64_t k = std::max<int64_t>(p[2] - 1, 0); k <= std::min(p[2], R[2] - 2); ++k)
          cell[(i * R[1] + j) * R[2] + k] = 1;
  }
}

// Dense grids: positive points as a volume, then OR with the +1 neighbour along z, y, x (in place: each pass
// reads entries it has not written yet); the last plane of each axis is no cell. O(X Y Z).
template <typename T>
void cells_from_volume(const int32_t* index, const T* dens, const int64_t* R, uint8_t* cell) {
  const int64_t X = R[0], Y = R[1], Z = R[2];
  for (int64_t p = 0; p < X * Y * Z; ++p) cell[p] = index[p] >= 0 && dens[index[p]] > 0;
  for (int64_t i = 0; i < X; ++i)
    for (int64_t j = 0; j < Y; ++j) {
      uint8_t* row = cell + (i * Y + j) * Z;
      for (int64_t k = 0; k + 1 < Z; ++k) row[k] |= row[k + 1];
      row[Z - 1] = 0;
    }
  for (int64_t i = 0; i < X; ++i) {
    uint8_t* plane = cell + i * Y * Z;
    for (int64_t j = 0; j + 1 < Y; ++j)
      for (int64_t k = 0; k < Z; ++k) plane[j * Z + k] |= plane[(j + 1) * Z + k];
    std::memset(plane + (Y - 1) * Z, 0, size_t(Z));
  }
  for (int64_t i = 0; i + 1 < X; ++i)
    for (int64_t q = 0; q < Y * Z; ++q) cell[i * Y * Z + q] |= cell[(i + 1) * Y * Z + q];
  std::memset(cell + (X - 1) * Y * Z, 0, size_t(Y * Z));
}

// One Chebyshev dilation (3 x 3 x 3 cube, separable) of `in` into `out`; `tmp` has the same size.
inline void dilate1(const uint8_t* in, uint8_t* out, uint8_t* tmp, const int64_t* B) {
  const int64_t n = B[0] * B[1] * B[2];
  const int64_t step[3] = {B[1] * B[2], B[2], 1};
  std::memcpy(out, in, size_t(n));
  for (int a = 0; a < 3; ++a) {
    std::memcpy(tmp, out, size_t(n));
    const int64_t outer = n / (B[a] * step[a]);
    for (int64_t o = 0; o < outer; ++o)
      for (int64_t c = 0; c < B[a]; ++c) {
        const int64_t base = (o * B[a] + c) * step[a];
        for (int64_t q = 0; q < step[a]; ++q) {
          uint8_t v = tmp[base + q];
          if (c > 0) v |= tmp[base + q - step[a]];
          if (c + 1 < B[a]) v |= tmp[base + q + step[a]];
          out[base + q] = v;
        }
      }
  }
}

// Block distances of a cell mask (see the top of this file).
inline void block_distance(const uint8_t* cell, const int64_t* R, int shift, const int64_t* B, uint8_t* dist) {
  const int64_t n = B[0] * B[1] * B[2];
  const size_t sz = static_cast<size_t>(n);
  std::vector<uint8_t> cover(sz, 0), next(sz, 0), tmp(sz, 0), acc(size_t(R[2]), 0);
  // a block is live when one of its cells is: OR the z rows of each (x, y) block column (vectorised), then
  // the 2^shift cells of each block along z (the last plane of each axis is no cell: zero in `cell`)
  const int64_t side = int64_t(1) << shift;
  for (int64_t bi = 0; bi < B[0]; ++bi)
    for (int64_t bj = 0; bj < B[1]; ++bj) {
      std::memset(acc.data(), 0, acc.size());
      for (int64_t i = bi * side; i < std::min((bi + 1) * side, R[0]); ++i)
        for (int64_t j = bj * side; j < std::min((bj + 1) * side, R[1]); ++j) {
          const uint8_t* row = cell + (i * R[1] + j) * R[2];
          for (int64_t k = 0; k < R[2]; ++k) acc[size_t(k)] |= row[k];
        }
      uint8_t* brow = cover.data() + (bi * B[1] + bj) * B[2];
      for (int64_t bk = 0; bk < B[2]; ++bk) {
        uint8_t v = 0;
        for (int64_t k = bk * side; k < std::min((bk + 1) * side, R[2]); ++k) v |= acc[size_t(k)];
        brow[bk] = v;
      }
    }
  for (int64_t p = 0; p < n; ++p) dist[p] = cover[p] ? 0 : uint8_t(kMaxDist + 1);
  for (int d = 1; d <= kMaxDist; ++d) {
    dilate1(cover.data(), next.data(), tmp.data(), B);
    bool dead_left = false;
    for (int64_t p = 0; p < n; ++p) {
      if (next[p] && !cover[p]) dist[p] = uint8_t(d);
      dead_left = dead_left || !next[p];
    }
    if (!dead_left) break;
    cover.swap(next);
  }
}

}  // namespace plx
