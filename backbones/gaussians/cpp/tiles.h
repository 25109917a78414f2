// The tile set-up and lane loops of the compositing kernels (composite3d.cpp, composite2d.cpp,
// composite2d_backward.cpp): the layout of a tile's pixel state, the loop over a tile's pixels, the tiles handed
// to the pool's workers, the forward passes' front-to-back walk over a tile's pairs and its live rows, and the
// rows a backward pass visits. Each kernel keeps its own per-pixel arithmetic (the lane loops' bodies).
#pragma once
#include <algorithm>
#include <cstdint>
#include <vector>

#include "common.h"

namespace arcsem {

// A tile's pixel state is lane-major: pixel (ly, lx) at ly * stride + lx, stride = the tile side rounded up to
// kLanes; K-vectors (composited features, their gradients) in blocks of kLanes pixels: component k of pixel
// (ly, lx) at lane_vec<K>(stride, ly, lx) + k * kLanes.
inline int lane_stride(int64_t tile) { return int((tile + kLanes - 1) / kLanes * kLanes); }

template <int K>
inline size_t lane_vec(int stride, int ly, int lx) {
  return size_t(ly * stride + lx / kLanes * kLanes) * K + lx % kLanes;
}

// f(i, pix, ly, lx) for every pixel (ly, lx) of tile ct, row by row: i its index in the tile state of row stride
// `stride`, pix its index in the [C, H, W] images.
template <class F>
inline void for_tile_pixels(const Grid& gr, int64_t ct, int stride, const F& f) {
  const int64_t c = ct / gr.tiles();
  for (int ly = 0; ly < int(gr.ny(ct)); ++ly)
    for (int lx = 0; lx < int(gr.nx(ct)); ++lx)
      f(int64_t(ly) * stride + lx, (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx, ly, lx);
}

// Every tile ct of every camera (ct = c * tiles + t) handed to the pool's workers one at a time (pool.h):
// f(ct, st), st the worker's tile state (State: Tile2 / Tile3), reset for the tile.
template <class State, class F>
inline void for_each_tile(const Grid& gr, const F& f) {
  std::vector<State> states(num_workers());
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    State& st = states[w];
    st.reset(gr.tile);
    f(ct, st);
  });
}

// A forward pass's walk over the n pairs of a tile, front to back, while a pixel is live (live_total > 0, which
// draw updates): the pairs are gathered in batches of kGatherBatch, gather(j0, j1), only as far as the walk goes
// (the pairs after every pixel stopped are not needed, not even by the backward pass); draw(j) composites pair j.
template <class Gather, class Draw>
inline void front_to_back(int64_t n, const int& live_total, const Gather& gather, const Draw& draw) {
  for (int64_t j = 0, have = 0; j < n && live_total > 0; ++j) {
    if (j == have) gather(j, have = std::min(n, j + kGatherBatch));
    draw(j);
  }
}

// The rows of pair q's box [q.y0, q.y1] with a live pixel (row_live[y] > 0) and on each the lane blocks of its
// columns [q.x0, q.x1] down to Min lanes (common.h): f(y, lanes, c) composites a block and returns how many of
// its pixels stopped, which leave row_live[y] and live_total.
template <int Min, class Q, class F>
inline void live_row_blocks(const Q& q, std::vector<int>& row_live, int& live_total, const F& f) {
  for (int y = q.y0; y <= q.y1; ++y) {
    if (row_live[y] == 0) continue;
    for_lane_blocks<Min>(q.x0, q.x1, [&](auto lanes, int c) {
      const int stops = f(y, lanes, c);
      row_live[y] -= stops;
      live_total -= stops;
    });
  }
}

// A backward pass's rows: row_live[y] = the last pair any pixel of tile row y composited (-1: none), from the
// per-pixel last pairs st.last (stride st.stride); returns the last over the tile's ny rows (-1: none).
template <class State>
inline int64_t last_composited(State& st, int ny) {
  int64_t jmax = -1;
  for (int y = 0; y < ny; ++y) {
    st.row_live[y] = -1;
    for (int x = 0; x < st.stride; ++x) st.row_live[y] = std::max(st.row_live[y], st.last[y * st.stride + x]);
    jmax = std::max<int64_t>(jmax, st.row_live[y]);
  }
  return jmax;
}

}  // namespace arcsem
