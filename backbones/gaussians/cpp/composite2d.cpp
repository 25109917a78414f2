// Fused CPU compositing of 2-D Gaussian surfels (2DGS): the forward pass (conventions: composite2d.h).
#include "composite2d.h"
#include "weights.h"

namespace arcsem {
namespace c2d {

// front to back over the n pairs of tile ct, gathered into pr in batches as far as the compositing goes (the
// pairs after every pixel stopped are not needed, not even by the backward pass); leaves the pixels' state in st
// and hands each lane block's weights to emit (weights.h; NoEmit: nothing)
template <typename T, class Emit>
void forward_tile(const In2<T>& in, const Entry2<T>* ent, const Grid& gr, int64_t ct, Pair2<T>* pr, int64_t n,
                  const T* mc, Tile2<T>& st, const Emit& emit) {
  const int S = st.stride;
  const T near = in.near, lp = in.lp;
  int live_total = start_tile(st, int(gr.nx(ct)), int(gr.ny(ct)));
  Lanes2<T> L;
  for (int64_t j = 0, have = 0; j < n && live_total > 0; ++j) {
    if (j == have) gather(ent, in.ids + in.off[ct], gr, ct, j, have = std::min(n, j + kGatherBatch), pr);
    const Pair2<T> q = pr[j];  // a local copy: its fields are loop invariants of the lane loops (no aliasing)
    uint32_t rows = 0;  // the tile rows where a live pixel drew the pair (the backward pass visits only those)
    if (q.x1 < q.x0 || q.y1 < q.y0) {
      pr[j].rows = 0;
      continue;
    }
    for (int y = q.y0; y <= q.y1; ++y) {
      if (st.row_live[y] == 0) continue;
      const T py = T(y) + T(0.5);
      for_lane_blocks<4>(q.x0, q.x1, [&](auto lanes, int c) {
        constexpr int NL = decltype(lanes)::value;
        const int base = y * S + c;
        T *tr = &st.tr[base], *lv = &st.live[base], *ws = &st.wsum[base], *acc = &st.acc[st.vec(y, c)], *wz = &st.wz[base], *m1 = &st.m1[base],
          *m2 = &st.m2[base], *dist = &st.dist[base], *mref = &st.mref[base], *med = &st.med[base];
        int32_t *ls = &st.last[base], *mi = &st.medi[base];
        if (!eval_lanes<NL>(q, c, py, near, lp, [&](int i) { return lv[i] > T(0); }, L)) return;
        if (y < 32) rows |= 1u << y;  // (a lane that stops here is not composited: the backward finds none)
        int stops = 0;
        alignas(64) T wl[NL];  // (read by an emitter only)
#pragma omp simd reduction(+ : stops)
        for (int i = 0; i < NL; ++i) {
          const Hit2<T> h = L[i];
          // every state value is read once and written back unconditionally (a select, then a full store): masked
          // stores would stall the next pair's loads of the same pixels (no store-to-load forwarding)
          const T T0 = tr[i], lv0 = lv[i], ws0 = ws[i], wz0 = wz[i], m10 = m1[i], m20 = m2[i], d0 = dist[i], mr0 = mref[i],
                  med0 = med[i];
          const int32_t ls0 = ls[i], mi0 = mi[i];
          const bool ok = h.ok;  // (and live)
          const T next = T0 * (T(1) - h.alpha);
          const bool stop = ok & (next < T(kMinT)), use = ok & !stop;
          const T w = use ? h.alpha * T0 : T(0);
          if constexpr (Emit::kOn) wl[i] = w;
          const T z = use ? h.z : T(1);  // finite where unused (the sums below add 0 there, never 0 * inf)
          const T m_abs = mc[0] + mc[1] * z + mc[2] / z;
          const T mr = (use & (ls0 < 0)) ? m_abs : mr0;
          const T m = m_abs - mr;
          dist[i] = d0 + (m * m * (T(1) - T0) + m20 - T(2) * m * m10) * w;
          wz[i] = wz0 + z * w;
          ws[i] = ws0 + w;
          m1[i] = m10 + m * w;
          m2[i] = m20 + m * m * w;
          mref[i] = mr;
          const bool median = use & (T0 > T(0.5));
          med[i] = median ? h.z : med0;
          mi[i] = median ? int32_t(j) : mi0;
#pragma GCC unroll 8
          for (int k = 0; k < K2; ++k) acc[k * kLanes + i] += w * q.f[k];
          tr[i] = use ? next : T0;
          ls[i] = use ? int32_t(j) : ls0;
          lv[i] = stop ? T(0) : lv0;
          stops += stop ? 1 : 0;
        }
        if constexpr (Emit::kOn) emit(y, c, NL, j, wl);
        st.row_live[y] -= stops;
        live_total -= stops;
      });
    }
    pr[j].rows = rows;
  }
}

template <typename T>
struct Out2 {
  T *rgb, *normal, *tf, *alpha, *wz, *depth, *median, *dist, *m1, *m2, *mref;
  int32_t *last, *medi;
};

// the tile's pixels into the output images (the background composited: rgb + (1 - alpha) bg)
template <typename T>
void write_tile(const Grid& gr, int64_t ct, int64_t start, const Tile2<T>& st, const T* bg, const Out2<T>& o) {
  const int64_t c = ct / gr.tiles();
  for (int64_t ly = 0; ly < gr.ny(ct); ++ly)
    for (int64_t lx = 0; lx < gr.nx(ct); ++lx) {
      const int64_t i = ly * st.stride + lx, pix = (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx;
      const T a = st.wsum[i];  // = 1 - T, without its cancellation for faint pixels
      const T* f = &st.acc[st.vec(int(ly), int(lx))];
      for (int k = 0; k < 3; ++k) {
        o.rgb[3 * pix + k] = f[k * kLanes] + (bg ? st.tr[i] * bg[k] : T(0));
        o.normal[3 * pix + k] = f[(3 + k) * kLanes];
      }
      o.tf[pix] = st.tr[i];
      o.alpha[pix] = a;
      o.wz[pix] = st.wz[i];
      o.depth[pix] = a > T(0) ? st.wz[i] / std::max(a, T(1e-30)) : T(0);
      o.median[pix] = st.med[i];
      o.dist[pix] = st.dist[i];
      o.m1[pix] = st.m1[i];
      o.m2[pix] = st.m2[i];
      o.mref[pix] = st.mref[i];
      o.last[pix] = st.last[i] < 0 ? -1 : int32_t(start + st.last[i]);
      o.medi[pix] = st.medi[i] < 0 ? -1 : int32_t(start + st.medi[i]);
    }
}

template <typename T>
Composite2D forward_impl(const Surfels2D& s, const TileLists& l, const Grid& gr) {
  const In2<T> in = inputs<T>(s, l);
  auto o = s.colors.options();
  Composite2D r;
  r.pairs = pair_storage<Pair2<T>>(l.ids.numel(), s.colors);
  for (auto* t : {&r.t_final, &r.alpha, &r.wz, &r.depth, &r.median, &r.distortion, &r.m1, &r.m2, &r.mref})
    *t = at::empty({gr.C, gr.H, gr.W, 1}, o);
  r.rgb = at::empty({gr.C, gr.H, gr.W, 3}, o);
  r.normal = at::empty({gr.C, gr.H, gr.W, 3}, o);
  r.last = at::empty({gr.C, gr.H, gr.W}, o.dtype(at::kInt));
  r.median_pair = at::empty_like(r.last);
  Pair2<T>* pairs = pair_records<Pair2<T>>(r.pairs);
  const Out2<T> out{r.rgb.data_ptr<T>(), r.normal.data_ptr<T>(), r.t_final.data_ptr<T>(), r.alpha.data_ptr<T>(),
                    r.wz.data_ptr<T>(), r.depth.data_ptr<T>(), r.median.data_ptr<T>(), r.distortion.data_ptr<T>(),
                    r.m1.data_ptr<T>(), r.m2.data_ptr<T>(), r.mref.data_ptr<T>(), r.last.data_ptr<int32_t>(),
                    r.median_pair.data_ptr<int32_t>()};
  const std::vector<Entry2<T>> ent = pack_entries(in, s.colors.size(0));
  std::vector<Tile2<T>> states(num_workers());
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    Tile2<T>& st = states[w];
    st.reset(gr.tile);
    const int64_t start = in.off[ct], c = ct / gr.tiles();
    forward_tile(in, ent.data(), gr, ct, pairs + start, in.off[ct + 1] - start, in.mc + 3 * c, st, NoEmit{});
    write_tile(gr, ct, start, st, in.bg, out);
  });
  return r;
}

template <typename T>
ColourWeights weights_impl(const Surfels2D& s, const TileLists& l, const Grid& gr) {
  const In2<T> in = inputs<T>(s, l);
  at::Tensor pairs = pair_storage<Pair2<T>>(l.ids.numel(), s.colors);
  const std::vector<Entry2<T>> ent = pack_entries(in, s.colors.size(0));
  return record_weights<T, Tile2<T>>(gr, in.off, l.ids.numel(), s.colors.options(),
                                     [&](int64_t ct, Tile2<T>& st, const WeightEmitter<T>& emit) {
    const int64_t start = in.off[ct];
    forward_tile(in, ent.data(), gr, ct, pair_records<Pair2<T>>(pairs) + start, in.off[ct + 1] - start,
                 in.mc + 3 * (ct / gr.tiles()), st, emit);
  });
}

}  // namespace c2d

Composite2D composite2d_forward(const Surfels2D& s, const TileLists& lists, const Raster& raster) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  TORCH_CHECK(lists.offsets.numel() == gr.C * gr.tiles() + 1, "composite2d: tile offsets must have C*tiles+1 entries");
  Composite2D r;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite2d_forward", [&] { r = c2d::forward_impl<scalar_t>(s, lists, gr); });
  return r;
}

ColourWeights composite2d_weights(const Surfels2D& s, const TileLists& lists, const Raster& raster) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  TORCH_CHECK(lists.offsets.numel() == gr.C * gr.tiles() + 1, "composite2d: tile offsets must have C*tiles+1 entries");
  ColourWeights r;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite2d_weights", [&] { r = c2d::weights_impl<scalar_t>(s, lists, gr); });
  return r;
}

}  // namespace arcsem
