// The cell a ray is in, cached while its samples stay in it (render.cpp): the 8 corners' rows, densities and
// colour dots dot[c][ch] = sum_k basis_k SH[row_c][k][ch] (the basis is the ray's), so that a sample costs
// 8 weights, a density and a colour of 8 terms, and the SH rows are read once per cell, not per sample:
// trilinear(SH) . basis = sum_c w_c (SH_c . basis). The backward sums each corner's gradient over the
// cell's samples and scatters it once, when the ray leaves the cell (CellGrad::flush).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "march.h"

namespace plx {

template <typename T, int DEG>
struct Cell {
  int64_t lin = -1;
  int64_t rows[8];
  bool has[8];
  T dens[8], dot[8][3];

  void load(const Grid& G, const T* density, const T* sh, int64_t stride, const T* basis, int64_t at) {
    lin = at;
    const int64_t Y = G.R[1], Z = G.R[2];
    for (int c = 0; c < 8; ++c) {
      const int32_t r = G.index[at + ((c >> 2) * Y + ((c >> 1) & 1)) * Z + (c & 1)];
      has[c] = r >= 0;
      rows[c] = has[c] ? r : 0;
      dens[c] = has[c] ? density[r] : T(0);
      T d0 = 0, d1 = 0, d2 = 0;
      if (has[c] && sh != nullptr) {  // sh == nullptr: densities only
        const T* q = sh + rows[c] * stride;
        for (int k = 0; k < num_coef<DEG>(); ++k) {
          d0 += basis[k] * q[3 * k];
          d1 += basis[k] * q[3 * k + 1];
          d2 += basis[k] * q[3 * k + 2];
        }
      }
      dot[c][0] = d0; dot[c][1] = d1; dot[c][2] = d2;
    }
  }

  // Trilinear weights of the sample (corner order i, j, k as in grid.py; 0 at empty corners) and its density.
  T weights(const T* f, T* w) const {
    T raw = 0;
    for (int c = 0; c < 8; ++c) {
      T wc = ((c >> 2) ? f[0] : 1 - f[0]) * (((c >> 1) & 1) ? f[1] : 1 - f[1]);
      wc *= (c & 1) ? f[2] : 1 - f[2];
      w[c] = has[c] ? wc : T(0);
      raw += w[c] * dens[c];
    }
    return raw;
  }

  // pre[ch] = 0.5 + sum_c w_c dot_c[ch]: the colour before ReLU.
  void colour(const T* w, T* pre) const {
    T p0 = 0, p1 = 0, p2 = 0;
    for (int c = 0; c < 8; ++c) {
      p0 += w[c] * dot[c][0];
      p1 += w[c] * dot[c][1];
      p2 += w[c] * dot[c][2];
    }
    pre[0] = p0 + T(0.5); pre[1] = p1 + T(0.5); pre[2] = p2 + T(0.5);
  }
};

// Where one thread's backward accumulates: the rows it touches get slots, in first-touch order, in a compact
// table (density gradient, then the SH row's) that stays as small as what the call touches; `slot` [M] maps a
// row to its slot (-1 at rest: kept between calls by fused.py, reset by collect in render.cpp). The adds
// then hit a table of the touched rows, not scattered lines of an [M]-sized one.
template <typename T>
struct Sink {
  static constexpr int kShift = 10;  // slots per chunk: 2^kShift (chunks are never moved: no copies as it grows)
  int32_t* slot = nullptr;           // [M]
  int64_t width = 1;                 // 1 + floats per SH row
  std::vector<int64_t> rows;         // slot -> row
  std::vector<std::unique_ptr<T[]>> chunks;  // [2^kShift, width] each, zeroed when made

  T* at(int64_t row) {
    int32_t s = slot[row];
    if (s < 0) {
      s = int32_t(rows.size());
      slot[row] = s;
      rows.push_back(row);
      if ((s & ((1 << kShift) - 1)) == 0) chunks.emplace_back(new T[size_t(width) << kShift]());
    }
    return get(s);
  }

  T* get(int32_t s) const { return chunks[size_t(s >> kShift)].get() + int64_t(s & ((1 << kShift) - 1)) * width; }
};

// A cell's gradients summed over its samples: density and colour dot of each corner.
template <typename T, int DEG>
struct CellGrad {
  T gdens[8] = {}, gdot[8][3] = {};
  bool used = false;

  void add(const T* w, T draw, const T* dpre) {
    for (int c = 0; c < 8; ++c) {
      gdens[c] += w[c] * draw;
      for (int ch = 0; ch < 3; ++ch) gdot[c][ch] += w[c] * dpre[ch];
    }
    used = true;
  }

  // Add into the sink (every stored corner gets a slot, even with a zero gradient: the optimiser steps the rows
  // a ray reached; SH gradient = basis_k * gdot[ch]) and reset.
  void flush(const Cell<T, DEG>& cell, const T* basis, Sink<T>& sink) {
    if (!used) return;
    for (int c = 0; c < 8; ++c) {
      if (!cell.has[c]) continue;
      T* q = sink.at(cell.rows[c]);
      q[0] += gdens[c];
      if (gdot[c][0] != 0 || gdot[c][1] != 0 || gdot[c][2] != 0)
        for (int k = 0; k < num_coef<DEG>(); ++k)
          for (int ch = 0; ch < 3; ++ch) q[1 + 3 * k + ch] += basis[k] * gdot[c][ch];
      gdens[c] = 0;
      gdot[c][0] = gdot[c][1] = gdot[c][2] = 0;
    }
    used = false;
  }
};

}  // namespace plx
