// Fused CPU compositing of 3-D Gaussians (3DGS) over tiles: forward and backward.
//
// Semantics equal the PyTorch reference path (backbones/gs3d/render.py) and the official rasteriser:
//   power = -0.5 (a dx^2 + c dy^2) - b dx dy; skip if power > 0
//   alpha = min(0.99, opacity exp(power)); skip if alpha < 1/255
//   stop before a splat whose composite would leave T < 1e-4
// Work: tiles are handed to threads one at a time (pool.h). Within a tile the splats are taken in depth order
// and each is evaluated on the tile rows its pixel box covers, kLanes pixels of a row at once (branch-free
// lanes that the compiler vectorises; float arithmetic for float tensors, double for double). The forward
// pass keeps its per-pair work list (the splat in the tile's pixel frame) for the backward pass, which
// writes one gradient row per pair; the rows are then summed per splat in the fixed order of the tile lists.
#include <cmath>
#include <vector>

#include "api.h"
#include "common.h"
#include "weights.h"

namespace arcsem {
namespace {

constexpr int K3 = 4;  // composited features: rgb, depth
constexpr int D3 = 6 + K3;  // gradient row: mean (2), conic (3), opacity, features

// One (tile, splat) pair in the tile's pixel frame: mean - tile origin, conic, opacity, features, and the
// splat's pixel box clipped to the tile (local, inclusive; empty when x1 < x0).
template <typename T>
struct Pair3 {
  T mx, my, ca, cb, cc, op, f[K3];
  int32_t x0, x1, y0, y1;
};

// Per-tile pixel state, lane-major: pixel (ly, lx) at ly * stride + lx, stride = tile rounded up to kLanes; the
// K-vectors (acc, go) in blocks of kLanes pixels: component k of pixel (ly, lx) at vec(ly, lx) + k * kLanes.
template <typename T>
struct Tile3 {
  int stride = 0, rows = 0;
  std::vector<T> tr, live, wsum, acc, sg, go, ga, tf;
  std::vector<int32_t> last, row_live;
  void reset(int64_t tile) {
    stride = int((tile + kLanes - 1) / kLanes * kLanes);
    rows = int(tile);
    const size_t n = size_t(stride) * rows;
    for (auto* v : {&tr, &live, &wsum, &sg, &ga, &tf}) v->assign(n, T(0));
    acc.assign(n * K3, T(0));
    go.assign(n * K3, T(0));
    last.assign(n, -1);
    row_live.assign(rows, 0);
  }
  size_t vec(int ly, int lx) const { return size_t(ly * stride + lx / kLanes * kLanes) * K3 + lx % kLanes; }
};

template <typename T>
struct In3 {
  const T *m2, *con, *op, *col, *dep, *bg;
  const int64_t *off, *ids, *box;
};

template <typename T>
In3<T> inputs(const Splats3D& s, const TileLists& l) {
  for (auto* t : {&s.means2d, &s.conics, &s.opacities, &s.colors, &s.depth}) check_cpu(*t, "composite3d input");
  for (auto* t : {&l.offsets, &l.ids, &l.box}) check_cpu(*t, "composite3d tile lists");
  return In3<T>{s.means2d.data_ptr<T>(), s.conics.data_ptr<T>(), s.opacities.data_ptr<T>(), s.colors.data_ptr<T>(),
                s.depth.data_ptr<T>(), grad_or_null<T>(s.background), l.offsets.data_ptr<int64_t>(),
                l.ids.data_ptr<int64_t>(), l.box.data_ptr<int64_t>()};
}

// pairs [j0, j1) of tile ct into out (its first pair at out[0])
template <typename T>
void gather(const In3<T>& in, const Grid& gr, int64_t ct, int64_t j0, int64_t j1, Pair3<T>* out) {
  const int64_t x0 = gr.x0(ct), y0 = gr.y0(ct), nx = gr.nx(ct), ny = gr.ny(ct);
  for (int64_t j = j0; j < j1; ++j) {
    const int64_t s = in.ids[in.off[ct] + j];
    Pair3<T>& q = out[j];
    q.mx = in.m2[2 * s] - T(x0);
    q.my = in.m2[2 * s + 1] - T(y0);
    q.ca = in.con[3 * s]; q.cb = in.con[3 * s + 1]; q.cc = in.con[3 * s + 2];
    q.op = in.op[s];
    for (int k = 0; k < 3; ++k) q.f[k] = in.col[3 * s + k];
    q.f[3] = in.dep[s];
    const int64_t* b = in.box + 4 * s;
    q.x0 = int32_t(std::max<int64_t>(b[0] - x0, 0)); q.x1 = int32_t(std::min<int64_t>(b[1] - x0, nx - 1));
    q.y0 = int32_t(std::max<int64_t>(b[2] - y0, 0)); q.y1 = int32_t(std::min<int64_t>(b[3] - y0, ny - 1));
  }
}

// power and alpha of splat q at lane pixel (lx, .) with dy precomputed; ok: inside the box and drawn
template <typename T>
inline void eval3(const Pair3<T>& q, int lx, T dy, T& dx, T& g, T& alpha, bool& ok) {
  dx = (T(lx) + T(0.5)) - q.mx;
  const T power = T(-0.5) * (q.ca * dx * dx + q.cc * dy * dy) - q.cb * dx * dy;
  g = vexp(power);
  alpha = std::min(T(kMaxAlpha), q.op * g);
  ok = (lx >= q.x0) & (lx <= q.x1) & (power <= T(0)) & (alpha >= T(kMinAlpha));  // no branches: vectorised
}

// front to back over the n pairs of tile ct, gathered into pr in batches as far as the compositing goes (the
// pairs after every pixel stopped are not needed, not even by the backward pass); leaves the pixels' state in st
// and hands each lane block's weights to emit (weights.h; NoEmit: nothing)
template <typename T, class Emit>
void forward_tile(const In3<T>& in, const Grid& gr, int64_t ct, Pair3<T>* pr, int64_t n, Tile3<T>& st,
                  const Emit& emit) {
  const int S = st.stride;
  int live_total = start_tile(st, int(gr.nx(ct)), int(gr.ny(ct)));
  for (int64_t j = 0, have = 0; j < n && live_total > 0; ++j) {
    if (j == have) gather(in, gr, ct, j, have = std::min(n, j + kGatherBatch), pr);
    const Pair3<T> q = pr[j];  // a local copy: its fields are loop invariants of the lane loops (no aliasing)
    if (q.x1 < q.x0 || q.y1 < q.y0) continue;
    for (int y = q.y0; y <= q.y1; ++y) {
      if (st.row_live[y] == 0) continue;
      const T dy = (T(y) + T(0.5)) - q.my;
      for_lane_blocks<4>(q.x0, q.x1, [&](auto lanes, int c) {
        constexpr int NL = decltype(lanes)::value;
        const int base = y * S + c;
        T *tr = st.tr.data() + base, *lv = st.live.data() + base, *acc = st.acc.data() + st.vec(y, c),
          *ws = st.wsum.data() + base;
        int32_t* ls = st.last.data() + base;
        int stops = 0;
        alignas(64) T wl[NL];  // (read by an emitter only)
#pragma omp simd reduction(+ : stops)
        for (int i = 0; i < NL; ++i) {
          T dx, g, alpha;
          bool ok;
          eval3(q, c + i, dy, dx, g, alpha, ok);
          // state read once, written back with full stores (masked stores would stall the next pair's loads of
          // the same pixels: no store-to-load forwarding)
          const T T0 = tr[i], lv0 = lv[i];
          const int32_t ls0 = ls[i];
          ok = ok & (lv0 > T(0));
          const T next = T0 * (T(1) - alpha);
          const bool stop = ok & (next < T(kMinT));
          const bool use = ok & !stop;
          const T w = use ? alpha * T0 : T(0);
          if constexpr (Emit::kOn) wl[i] = w;
#pragma GCC unroll 8
          for (int k = 0; k < K3; ++k) acc[k * kLanes + i] += w * q.f[k];
          ws[i] += w;
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
  }
}

template <typename T>
Composite3D forward_impl(const Splats3D& s, const TileLists& l, const Grid& gr) {
  const In3<T> in = inputs<T>(s, l);
  const int64_t P = l.ids.numel();
  auto o = s.colors.options();
  Composite3D r;
  r.pairs = pair_storage<Pair3<T>>(P, s.colors);
  r.t_final = at::empty({gr.C, gr.H, gr.W, 1}, o);
  r.wz = at::empty_like(r.t_final);
  r.alpha = at::empty_like(r.t_final);
  r.depth = at::empty_like(r.t_final);
  r.rgb = at::empty({gr.C, gr.H, gr.W, 3}, o);
  r.last = at::empty({gr.C, gr.H, gr.W}, o.dtype(at::kInt));
  Pair3<T>* pairs = pair_records<Pair3<T>>(r.pairs);
  T *rgb = r.rgb.data_ptr<T>(), *tf = r.t_final.data_ptr<T>(), *wz = r.wz.data_ptr<T>(), *al = r.alpha.data_ptr<T>(),
    *dep = r.depth.data_ptr<T>();
  int32_t* last = r.last.data_ptr<int32_t>();
  std::vector<Tile3<T>> states(num_workers());
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    Tile3<T>& st = states[w];
    st.reset(gr.tile);
    const int64_t start = in.off[ct], n = in.off[ct + 1] - start, c = ct / gr.tiles();
    forward_tile(in, gr, ct, pairs + start, n, st, NoEmit{});
    for (int ly = 0; ly < int(gr.ny(ct)); ++ly)
      for (int lx = 0; lx < int(gr.nx(ct)); ++lx) {
        const int64_t i = ly * st.stride + lx, pix = (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx;
        const T* f = st.acc.data() + st.vec(ly, lx);
        const T a = st.wsum[i];  // = 1 - T, without its cancellation for faint pixels
        for (int k = 0; k < 3; ++k) rgb[3 * pix + k] = f[k * kLanes] + (in.bg ? st.tr[i] * in.bg[k] : T(0));
        tf[pix] = st.tr[i];
        al[pix] = a;
        wz[pix] = f[3 * kLanes];
        dep[pix] = a > T(0) ? wz[pix] / std::max(a, T(1e-30)) : T(0);
        last[pix] = st.last[i] < 0 ? -1 : int32_t(start + st.last[i]);
      }
  });
  return r;
}

// Back to front over the tile's pairs from the last one any pixel composited; one gradient row per pair.
// Returns the number of pairs with rows (from the first one to the last one composited).
template <typename T>
int64_t backward_tile(const Pair3<T>* pr, int ny, Tile3<T>& st, T* grow) {
  const int S = st.stride;
  int64_t jmax = -1;
  for (int y = 0; y < ny; ++y) {  // row_live[y]: the last pair any pixel of row y composited (-1: none)
    st.row_live[y] = -1;
    for (int x = 0; x < S; ++x) st.row_live[y] = std::max(st.row_live[y], st.last[y * S + x]);
    jmax = std::max<int64_t>(jmax, st.row_live[y]);
  }
  alignas(64) T acc[D3][kLanes];
  for (int32_t j = int32_t(jmax); j >= 0; --j) {
    const Pair3<T> q = pr[j];  // a local copy: its fields are loop invariants of the lane loops (no aliasing)
    for (auto& a : acc) std::fill(a, a + kLanes, T(0));
    for (int y = q.y0; y <= q.y1 && q.x0 <= q.x1; ++y) {
      if (j > st.row_live[y]) continue;  // the row's pixels all stopped before this pair
      const T dy = (T(y) + T(0.5)) - q.my;
      for_lane_blocks<8>(q.x0, q.x1, [&](auto lanes, int c) {
        constexpr int NL = decltype(lanes)::value;
        const int base = y * S + c;
        T *tr = st.tr.data() + base, *sg = st.sg.data() + base;
        const T *go = st.go.data() + st.vec(y, c), *ga = st.ga.data() + base, *tf = st.tf.data() + base;
        const int32_t* ls = st.last.data() + base;
#pragma omp simd
        for (int i = 0; i < NL; ++i) {
          T dx, g, alpha;
          bool ok;
          eval3(q, c + i, dy, dx, g, alpha, ok);
          // state read once, written back with full stores (see forward_tile); w = 0 on unused lanes
          const T tr0 = tr[i], sg0 = sg[i];
          ok = ok & (j <= ls[i]);
          const T inv = T(1) / (T(1) - alpha), Ti = tr0 * inv, w = ok ? alpha * Ti : T(0);
          T gof = 0;
#pragma GCC unroll 8
          for (int k = 0; k < K3; ++k) gof += go[k * kLanes + i] * q.f[k];
          // alpha_out = 1 - T_final: d/d alpha_i gets g_alpha T_final / (1 - alpha_i)
          const T dalpha = ga[i] * tf[i] * inv + Ti * gof - sg0 * inv;
          sg[i] = sg0 + w * gof;
          tr[i] = ok ? Ti : tr0;
#pragma GCC unroll 8
          for (int k = 0; k < K3; ++k) acc[6 + k][i] += w * go[k * kLanes + i];
          const bool grad = ok & (q.op * g <= T(kMaxAlpha));  // clamped alpha has no gradient
          const T dpow = grad ? dalpha * q.op * g : T(0);
          acc[5][i] += grad ? dalpha * g : T(0);
          acc[0][i] += dpow * (q.ca * dx + q.cb * dy);  // d power / d mean
          acc[1][i] += dpow * (q.cb * dx + q.cc * dy);
          acc[2][i] += dpow * T(-0.5) * dx * dx;
          acc[3][i] += -dpow * dx * dy;
          acc[4][i] += dpow * T(-0.5) * dy * dy;
        }
      });
    }
    for (int d = 0; d < D3; ++d) {
      T sum = 0;
      for (int i = 0; i < kLanes; ++i) sum += acc[d][i];
      grow[j * D3 + d] = sum;
    }
  }
  return jmax + 1;
}

template <typename T>
Grads3D backward_impl(const Splats3D& s, const TileLists& l, const Grid& gr, const Composite3D& fw,
                      const at::Tensor& g_rgb, const at::Tensor& g_alpha, const at::Tensor& g_depth) {
  const In3<T> in = inputs<T>(s, l);
  const int64_t M = s.colors.size(0), P = l.ids.numel();
  const Pair3<T>* pairs = pair_records<Pair3<T>>(fw.pairs);
  const T *tf = fw.t_final.data_ptr<T>(), *al = fw.alpha.data_ptr<T>(), *wz = fw.wz.data_ptr<T>();
  const int32_t* last = fw.last.data_ptr<int32_t>();
  const T *gr_rgb = grad_or_null<T>(g_rgb), *gr_al = grad_or_null<T>(g_alpha), *gr_dep = grad_or_null<T>(g_depth);
  PairRows<T> rows(P, D3);
  std::vector<Tile3<T>> states(num_workers());
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    Tile3<T>& st = states[w];
    st.reset(gr.tile);
    const int64_t start = in.off[ct], c = ct / gr.tiles();
    for (int ly = 0; ly < int(gr.ny(ct)); ++ly)
      for (int lx = 0; lx < int(gr.nx(ct)); ++lx) {
        const int64_t i = ly * st.stride + lx, pix = (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx;
        T* go = st.go.data() + st.vec(ly, lx);
        // rgb = f + (1 - alpha) bg, depth = wz / alpha: gradients to the composited features and to alpha
        const T a = al[pix];
        T ga = gr_al ? gr_al[pix] : T(0);
        for (int k = 0; k < 3; ++k) {
          const T gk = gr_rgb ? gr_rgb[3 * pix + k] : T(0);
          go[k * kLanes] = gk;
          if (in.bg) ga -= gk * in.bg[k];
        }
        T gw = 0;
        if (gr_dep && a > T(0)) {
          const T ac = std::max(a, T(1e-30));
          gw = gr_dep[pix] / ac;
          if (a >= T(1e-30)) ga -= gr_dep[pix] * wz[pix] / (ac * ac);
        }
        go[3 * kLanes] = gw;
        st.ga[i] = ga;
        st.tf[i] = st.tr[i] = tf[pix];
        st.last[i] = last[pix] < 0 ? -1 : int32_t(last[pix] - start);
      }
    rows.mark(start, in.off[ct + 1] - start, backward_tile(pairs + start, int(gr.ny(ct)), st, rows.tile(start)));
  });
  Grads3D g;
  g.means2d = at::empty_like(s.means2d);
  g.conics = at::empty_like(s.conics);
  g.opacities = at::empty_like(s.opacities);
  g.colors = at::empty_like(s.colors);
  g.depth = at::empty_like(s.depth);
  T *gm = g.means2d.data_ptr<T>(), *gc = g.conics.data_ptr<T>(), *go = g.opacities.data_ptr<T>(),
    *gcol = g.colors.data_ptr<T>(), *gd = g.depth.data_ptr<T>();
  reduce_pairs<D3>(M, rows, l.entry_offsets.data_ptr<int64_t>(), l.pair_of.data_ptr<int64_t>(),
               [&](int64_t e, const double* r) {
                 gm[2 * e] = T(r[0]);
                 gm[2 * e + 1] = T(r[1]);
                 for (int k = 0; k < 3; ++k) gc[3 * e + k] = T(r[2 + k]);
                 go[e] = T(r[5]);
                 for (int k = 0; k < 3; ++k) gcol[3 * e + k] = T(r[6 + k]);
                 gd[e] = T(r[9]);
               });
  return g;
}

template <typename T>
ColourWeights weights_impl(const Splats3D& s, const TileLists& l, const Grid& gr) {
  const In3<T> in = inputs<T>(s, l);
  at::Tensor pairs = pair_storage<Pair3<T>>(l.ids.numel(), s.colors);
  return record_weights<T, Tile3<T>>(gr, in.off, l.ids.numel(), s.colors.options(),
                                     [&](int64_t ct, Tile3<T>& st, const WeightEmitter<T>& emit) {
    const int64_t start = in.off[ct];
    forward_tile(in, gr, ct, pair_records<Pair3<T>>(pairs) + start, in.off[ct + 1] - start, st, emit);
  });
}

}  // namespace

ColourWeights composite3d_weights(const Splats3D& s, const TileLists& lists, const Raster& raster) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  TORCH_CHECK(lists.offsets.numel() == gr.C * gr.tiles() + 1, "composite3d: tile offsets must have C*tiles+1 entries");
  ColourWeights r;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite3d_weights", [&] { r = weights_impl<scalar_t>(s, lists, gr); });
  return r;
}

Composite3D composite3d_forward(const Splats3D& s, const TileLists& lists, const Raster& raster) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  TORCH_CHECK(lists.offsets.numel() == gr.C * gr.tiles() + 1, "composite3d: tile offsets must have C*tiles+1 entries");
  Composite3D r;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite3d_forward", [&] { r = forward_impl<scalar_t>(s, lists, gr); });
  return r;
}

Grads3D composite3d_backward(const Splats3D& s, const TileLists& lists, const Raster& raster, const Composite3D& fwd,
                             const at::Tensor& g_rgb, const at::Tensor& g_alpha, const at::Tensor& g_depth) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  Grads3D g;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite3d_backward", [&] {
    g = backward_impl<scalar_t>(s, lists, gr, fwd, g_rgb, g_alpha, g_depth);
  });
  return g;
}

}  // namespace arcsem
