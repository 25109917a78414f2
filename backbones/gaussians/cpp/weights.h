// The compositing weights of a frozen geometry: w = alpha T of every (pixel, pair) a forward pass composited.
// With the geometry fixed (stage 2) a render is linear in the colours, rgb = W colours[ids] + T_final bg, so the
// weights, recorded once per view, replace the compositing of every later step (composite2d/3d_weights).
// A forward pass (forward_tile) takes an emitter: NoEmit (the normal pass, compiled away) or WeightEmitter.
#pragma once
#include <cstdint>
#include <vector>

#include "api.h"
#include "common.h"

namespace arcsem {

struct NoEmit {
  static constexpr bool kOn = false;
  template <class... A>
  void operator()(A&&...) const {}
};

template <typename T>
struct WeightRecord {
  int32_t pix, pair;  // pixel c*H*W + y*W + x; pair position in the tile lists
  T w;
};

// The records of one tile, in the order the forward pass composites: pair by pair (depth order), then row, lane.
template <typename T>
struct WeightEmitter {
  static constexpr bool kOn = true;
  std::vector<WeightRecord<T>>* out;
  int64_t pix0, W, start;  // the tile's first pixel, the image width, its first pair
  // lanes [0, NL) of tile row y from column c drew local pair j with weights w (0: not composited)
  void operator()(int y, int c, int NL, int64_t j, const T* w) const {
    for (int i = 0; i < NL; ++i)
      if (w[i] > T(0)) out->push_back({int32_t(pix0 + int64_t(y) * W + c + i), int32_t(start + j), w[i]});
  }
};

template <typename T>
WeightEmitter<T> tile_emitter(std::vector<WeightRecord<T>>* out, const Grid& gr, int64_t ct, int64_t start) {
  const int64_t c = ct / gr.tiles();
  return WeightEmitter<T>{out, (c * gr.H + gr.y0(ct)) * gr.W + gr.x0(ct), gr.W, start};
}

// the final transmittance of a tile's pixels (a forward pass's state st) into t [C*H*W]
template <typename T, class St>
void write_transmittance(const Grid& gr, int64_t ct, const St& st, T* t) {
  const int64_t c = ct / gr.tiles();
  for (int64_t ly = 0; ly < gr.ny(ct); ++ly)
    for (int64_t lx = 0; lx < gr.nx(ct); ++lx)
      t[(c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx] = st.tr[size_t(ly * st.stride + lx)];
}

// the per-tile records (tiles[ct]) as CSR over the pixels, each row in depth order; t_final is the forward pass's,
// passed through. A tile's records are its own pixels' (and its own pairs'), so tiles fill their rows in parallel.
template <typename T>
ColourWeights assemble_weights(const std::vector<std::vector<WeightRecord<T>>>& tiles, int64_t npix, int64_t npairs,
                               const at::TensorOptions& o, const at::Tensor& t_final) {
  int64_t nnz = 0;
  for (const auto& t : tiles) nnz += int64_t(t.size());
  TORCH_CHECK(nnz < (int64_t(1) << 31) && npix < (int64_t(1) << 31) && npairs < (int64_t(1) << 31),
              "compositing weights: more than 2^31 records, pixels or pairs");
  ColourWeights r;
  r.t_final = t_final;
  r.npairs = npairs;
  r.pix_ptr = at::zeros({npix + 1}, o.dtype(at::kInt));
  r.pix_pair = at::empty({nnz}, o.dtype(at::kInt));
  r.pix_w = at::empty({nnz}, o);
  int32_t *pp = r.pix_ptr.data_ptr<int32_t>(), *pc = r.pix_pair.data_ptr<int32_t>();
  T* pw = r.pix_w.data_ptr<T>();
  parallel_chunks(int64_t(tiles.size()), [&](int64_t ct, int) {
    for (const auto& e : tiles[size_t(ct)]) ++pp[e.pix + 1];
  });
  for (int64_t i = 0; i < npix; ++i) pp[i + 1] += pp[i];
  std::vector<int32_t> cursor(pp, pp + npix);
  parallel_chunks(int64_t(tiles.size()), [&](int64_t ct, int) {
    for (const auto& e : tiles[size_t(ct)]) {  // pair by pair: each pixel's row fills in depth order
      const int32_t p = cursor[size_t(e.pix)]++;
      pc[p] = e.pair;
      pw[p] = e.w;
    }
  });
  return r;
}

// A forward pass's record: run(ct, state, emitter) composites tile ct (its pairs from off[ct]) with the emitter,
// leaving its pixels' state; the tiles run in parallel, each worker with a Tile state of its own.
template <typename T, class Tile, class Run>
ColourWeights record_weights(const Grid& gr, const int64_t* off, int64_t npairs, const at::TensorOptions& o,
                             const Run& run) {
  std::vector<Tile> states(num_workers());
  std::vector<std::vector<WeightRecord<T>>> recs(size_t(gr.C * gr.tiles()));
  at::Tensor tf = at::empty({gr.C * gr.H * gr.W}, o);
  T* tfp = tf.data_ptr<T>();
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    Tile& st = states[w];
    st.reset(gr.tile);
    run(ct, st, tile_emitter(&recs[size_t(ct)], gr, ct, off[ct]));
    write_transmittance(gr, ct, st, tfp);
  });
  return assemble_weights(recs, gr.C * gr.H * gr.W, npairs, o, tf);
}

}  // namespace arcsem
