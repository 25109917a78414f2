// Fused CPU compositing of 2-D Gaussian surfels (2DGS): the backward pass (conventions: composite2d.h).
//
// Per pixel, back to front from its last composited pair, the transmittance is restored (T_i = T_{i+1} /
// (1 - alpha_i)) and every output's gradient is taken to the pair's weight w_i = alpha_i T_i, depth z_i and
// features; alpha_i then goes to the opacity and the Gaussian's exponent, and the exponent and z_i to the
// adjugate columns, the depth row or the centre. Each pair gets one gradient row (the sum over its pixels);
// the rows are summed per entry in the tile lists' fixed order and the adjugate gradient taken to H.
#include "composite2d.h"

namespace arcsem {
namespace c2d {
namespace {

template <typename T>
struct Saved2 {  // per-pixel values of the forward pass and output gradients (null: zero)
  const T *tf, *alpha, *wz, *m1, *m2, *mref;
  const int32_t *last, *medi;
  const T *g_rgb, *g_nrm, *g_alpha, *g_depth, *g_med, *g_dist;
};

// the pixel state of tile ct for its backward pass: gradients of the composited sums and the forward's per-pixel values
template <typename T>
void load_tile(const Grid& gr, int64_t ct, int64_t start, const Saved2<T>& sv, const T* bg, Tile2<T>& st) {
  const int64_t c = ct / gr.tiles();
  for (int64_t ly = 0; ly < gr.ny(ct); ++ly)
    for (int64_t lx = 0; lx < gr.nx(ct); ++lx) {
      const int64_t i = ly * st.stride + lx, pix = (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx;
      const T a = sv.alpha[pix];
      T* go = &st.go[st.vec(int(ly), int(lx))];
      T ga = sv.g_alpha ? sv.g_alpha[pix] : T(0);
      for (int k = 0; k < 3; ++k) {  // rgb = sum w c + (1 - alpha) bg
        const T gk = sv.g_rgb ? sv.g_rgb[3 * pix + k] : T(0);
        go[k * kLanes] = gk;
        go[(3 + k) * kLanes] = sv.g_nrm ? sv.g_nrm[3 * pix + k] : T(0);
        if (bg) ga -= gk * bg[k];
      }
      T gd = 0;  // depth = sum w z / alpha
      if (sv.g_depth && a > T(0)) {
        const T ac = std::max(a, T(1e-30));
        gd = sv.g_depth[pix] / ac;
        if (a >= T(1e-30)) ga -= sv.g_depth[pix] * sv.wz[pix] / (ac * ac);
      }
      st.ga[i] = ga;
      st.gd[i] = gd;
      st.gm[i] = sv.g_med ? sv.g_med[pix] : T(0);
      st.gdis[i] = sv.g_dist ? sv.g_dist[pix] : T(0);
      st.tf[i] = st.tr[i] = sv.tf[pix];
      st.m1[i] = sv.m1[pix];
      st.m2[i] = sv.m2[pix];
      st.mref[i] = sv.mref[pix];
      st.last[i] = sv.last[pix] < 0 ? -1 : int32_t(sv.last[pix] - start);
      st.medi[i] = sv.medi[pix] < 0 ? -1 : int32_t(sv.medi[pix] - start);
    }
}

// pair q on NL pixels of row y from column c: adds the pixels' gradients into acc [D2][kLanes] (lanes < NL)
template <int NL, typename T>
inline void backward_lanes(const Pair2<T> q, int32_t j, int y, int c, const T* mcoef, T near, T lp, Tile2<T>& st,
                           T (*acc)[kLanes]) {
  const int base = y * st.stride + c;
  const T py = T(y) + T(0.5), mc[3] = {mcoef[0], mcoef[1], mcoef[2]};
  T *tr = &st.tr[base], *sa = &st.s[base];
  const T *tf = &st.tf[base], *m1 = &st.m1[base], *m2 = &st.m2[base], *mref = &st.mref[base], *go = &st.go[st.vec(y, c)],
          *ga = &st.ga[base], *gd = &st.gd[base], *gm = &st.gm[base], *gdis = &st.gdis[base];
  const int32_t *ls = &st.last[base], *mi = &st.medi[base];
  Lanes2<T> L;
  if (!eval_lanes<NL>(q, c, py, near, lp, [&](int i) { return j <= ls[i]; }, L)) return;
#pragma omp simd
  for (int i = 0; i < NL; ++i) {
    const Hit2<T> h = L[i];
    // state read once, written back with full stores (a masked store would stall the next pair's loads of the
    // same pixels); unused lanes get finite stand-ins so that their contributions are exact zeros
    const T tr0 = tr[i], sa0 = sa[i], gmi = gm[i];
    const bool ok = h.ok;  // (and composited: j <= last)
    const T z = ok ? h.z : T(1);
    const T inv = T(1) / (T(1) - h.alpha), Ti = tr0 * inv, w = ok ? h.alpha * Ti : T(0), Wt = T(1) - tf[i];
    const T iz = T(1) / z;
    const T m = mc[0] + mc[1] * z + mc[2] * iz - mref[i];
    const T dm_dz = mc[1] - mc[2] * iz * iz;
    // dL/dw_i: every output is a sum over w_i of a per-splat value
    T gw = ga[i] + gd[i] * z + gdis[i] * (m * m * Wt - T(2) * m * m1[i] + m2[i]);
#pragma GCC unroll 8
    for (int k = 0; k < K2; ++k) {
      gw += go[k * kLanes + i] * q.f[k];
      acc[GF + k][i] += w * go[k * kLanes + i];
    }
    const T gz = w * gd[i] + gdis[i] * T(2) * w * (m * Wt - m1[i]) * dm_dz + ((ok & (mi[i] == j)) ? gmi : T(0));
    const T dalpha = gw * Ti - sa0 * inv;
    sa[i] = sa0 + gw * w;
    tr[i] = ok ? Ti : tr0;
    const bool grad = ok & (q.op * h.g <= T(kMaxAlpha));  // clamped alpha has no gradient
    const T dpow = grad ? dalpha * q.op * h.g : T(0);
    acc[GOP][i] += grad ? dalpha * h.g : T(0);
    const bool h3 = ok & h.use3d, h2 = ok & !h.use3d;
    // 3-D hit: power = -0.5 (u^2 + v^2), z = u Dz.x + v Dz.y + Dz.z, (u, v) = (p.x, p.y) / p.z, p = x a + y b + c
    const T gu = h3 ? -dpow * h.u + gz * q.dz[0] : T(0), gv = h3 ? -dpow * h.v + gz * q.dz[1] : T(0);
    const T gp0 = gu * h.ip, gp1 = gv * h.ip, gp2 = -(gu * h.u + gv * h.v) * h.ip;
    const T px = T(c + i) + T(0.5);
    acc[GA + 0][i] += px * gp0; acc[GA + 1][i] += px * gp1; acc[GA + 2][i] += px * gp2;
    acc[GA + 3][i] += py * gp0; acc[GA + 4][i] += py * gp1; acc[GA + 5][i] += py * gp2;
    acc[GA + 6][i] += gp0; acc[GA + 7][i] += gp1; acc[GA + 8][i] += gp2;
    acc[GDZ + 0][i] += h3 ? gz * h.u : T(0);
    acc[GDZ + 1][i] += h3 ? gz * h.v : T(0);
    acc[GDZ + 2][i] += ok ? gz : T(0);
    // 2-D (low-pass) hit: power = -lp |c - pixel|^2 / 2, z = Dz.z
    acc[GC + 0][i] += h2 ? dpow * -lp * h.dx : T(0);
    acc[GC + 1][i] += h2 ? dpow * -lp * h.dy : T(0);
  }
}

// colours only (frozen geometry): pair q on NL pixels of row y from column c adds w go_rgb into acc [3][kLanes]
template <int NL, typename T>
inline void colour_lanes(const Pair2<T> q, int32_t j, int y, int c, T near, T lp, Tile2<T>& st, T (*acc)[kLanes]) {
  const int base = y * st.stride + c;
  const T py = T(y) + T(0.5);
  T* tr = &st.tr[base];
  const T* go = &st.go[st.vec(y, c)];
  const int32_t* ls = &st.last[base];
  Lanes2<T> L;
  if (!eval_lanes<NL>(q, c, py, near, lp, [&](int i) { return j <= ls[i]; }, L)) return;
#pragma omp simd
  for (int i = 0; i < NL; ++i) {
    const T tr0 = tr[i], alpha = L.alpha[i];
    const bool ok = L.ok[i] != 0;
    const T Ti = tr0 / (T(1) - alpha), w = ok ? alpha * Ti : T(0);
    for (int k = 0; k < 3; ++k) acc[k][i] += w * go[k * kLanes + i];
    tr[i] = ok ? Ti : tr0;
  }
}

// back to front over the tile's pairs from the last one any pixel composited; one gradient row per pair (D2
// values; Geo = false: the 3 colour values). Returns the number of pairs with rows (up to the last composited).
template <typename T, bool Geo>
int64_t backward_tile(const Pair2<T>* pr, int ny, const T* mc, T near, T lp, int64_t x0, int64_t y0, Tile2<T>& st,
                      T* rows) {
  constexpr int D = Geo ? D2 : 3;
  int64_t jmax = -1;
  for (int y = 0; y < ny; ++y) {  // row_live[y]: the last pair any pixel of row y composited (-1: none)
    st.row_live[y] = -1;
    for (int x = 0; x < st.stride; ++x) st.row_live[y] = std::max(st.row_live[y], st.last[y * st.stride + x]);
    jmax = std::max<int64_t>(jmax, st.row_live[y]);
  }
  alignas(64) T acc[D][kLanes];
  for (int64_t j = jmax; j >= 0; --j) {
    const Pair2<T> q = pr[j];  // a local copy: its fields are loop invariants of the lane loops (no aliasing)
    for (auto& a : acc) std::fill(a, a + kLanes, T(0));
    for (int y = q.y0; y <= q.y1 && q.x0 <= q.x1; ++y) {
      if (j > st.row_live[y] || !composited_row(q.rows, y)) continue;  // stopped before it, or none composited
      for_lane_blocks<8>(q.x0, q.x1, [&](auto lanes, int c) {
        constexpr int NL = decltype(lanes)::value;
        if constexpr (Geo) backward_lanes<NL>(q, int32_t(j), y, c, mc, near, lp, st, acc);
        else colour_lanes<NL>(q, int32_t(j), y, c, near, lp, st, acc);
      });
    }
    T* r = rows + j * D;
    for (int d = 0; d < D; ++d) {
      T sum = 0;
      for (int i = 0; i < kLanes; ++i) sum += acc[d][i];
      r[d] = sum;
    }
    if constexpr (Geo)
      for (int k = 0; k < 3; ++k) {  // from the tile frame: c' = c + x0 a + y0 b
        r[GA + k] += T(x0) * r[GA + 6 + k];
        r[GA + 3 + k] += T(y0) * r[GA + 6 + k];
      }
  }
  return jmax + 1;
}

// a = Tv x Tw, b = Tw x Tu, c = Tu x Tv: gradients of (a, b, c) -> of the rows Tu, Tv, Tw (gH[9])
inline void adjugate_to_rows(const double* H, const double* gA, double* gH) {
  const double *Tu = H, *Tv = H + 3, *Tw = H + 6, *ga = gA, *gb = gA + 3, *gc = gA + 6;
  double t[3];
  std::fill(gH, gH + 9, 0.0);
  auto add = [&](int row, const double* x, const double* y) {  // gH[row] += x cross y
    cross(x, y, t);
    for (int j = 0; j < 3; ++j) gH[3 * row + j] += t[j];
  };
  add(1, Tw, ga); add(2, ga, Tv);  // g.(u x v): d/du = v x g, d/dv = g x u
  add(2, Tu, gb); add(0, gb, Tw);
  add(0, Tv, gc); add(1, gc, Tu);
}

template <typename T>
Grads2D backward_impl(const Surfels2D& s, const TileLists& l, const Grid& gr, const Composite2D& fw,
                      const std::vector<at::Tensor>& og, bool geometry) {
  const In2<T> in = inputs<T>(s, l);
  const int64_t M = s.colors.size(0), P = l.ids.numel();
  const Pair2<T>* pairs = pair_records<Pair2<T>>(fw.pairs);
  const Saved2<T> sv{fw.t_final.data_ptr<T>(), fw.alpha.data_ptr<T>(), fw.wz.data_ptr<T>(), fw.m1.data_ptr<T>(),
                     fw.m2.data_ptr<T>(), fw.mref.data_ptr<T>(), fw.last.data_ptr<int32_t>(),
                     fw.median_pair.data_ptr<int32_t>(), grad_or_null<T>(og[0]), grad_or_null<T>(og[1]),
                     grad_or_null<T>(og[2]), grad_or_null<T>(og[3]), grad_or_null<T>(og[4]), grad_or_null<T>(og[5])};
  const int64_t D = geometry ? D2 : 3;
  PairRows<T> rows(P, D);
  std::vector<Tile2<T>> states(num_workers());
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int w) {
    Tile2<T>& st = states[w];
    st.reset(gr.tile);
    const int64_t start = in.off[ct], n = in.off[ct + 1] - start;
    load_tile(gr, ct, start, sv, in.bg, st);
    const T* mc = in.mc + 3 * (ct / gr.tiles());
    const Pair2<T>* pr = pairs + start;
    const int ny = int(gr.ny(ct));
    T* r = rows.tile(start);
    const int64_t k = geometry ? backward_tile<T, true>(pr, ny, mc, in.near, in.lp, gr.x0(ct), gr.y0(ct), st, r)
                               : backward_tile<T, false>(pr, ny, mc, in.near, in.lp, gr.x0(ct), gr.y0(ct), st, r);
    rows.mark(start, n, k);
  });
  Grads2D g;
  if (!geometry) {
    g.colors = at::empty_like(s.colors);
    T* gcol = g.colors.data_ptr<T>();
    reduce_pairs<3>(M, rows, l.entry_offsets.data_ptr<int64_t>(), l.pair_of.data_ptr<int64_t>(),
                 [&](int64_t e, const double* r) { for (int k = 0; k < 3; ++k) gcol[3 * e + k] = T(r[k]); });
    return g;
  }
  g.H = at::empty_like(s.H);
  g.Dz = at::empty_like(s.Dz);
  g.centres = at::empty_like(s.centres);
  g.opacities = at::empty_like(s.opacities);
  g.colors = at::empty_like(s.colors);
  g.normals = at::empty_like(s.normals);
  T *gH = g.H.data_ptr<T>(), *gDz = g.Dz.data_ptr<T>(), *gc = g.centres.data_ptr<T>(), *gop = g.opacities.data_ptr<T>(),
    *gcol = g.colors.data_ptr<T>(), *gn = g.normals.data_ptr<T>();
  reduce_pairs<D2>(M, rows, l.entry_offsets.data_ptr<int64_t>(), l.pair_of.data_ptr<int64_t>(),
               [&](int64_t e, const double* r) {
                 double H[9], h[9];
                 for (int k = 0; k < 9; ++k) H[k] = double(in.H[9 * e + k]);
                 adjugate_to_rows(H, r + GA, h);
                 for (int k = 0; k < 9; ++k) gH[9 * e + k] = T(h[k]);
                 for (int k = 0; k < 3; ++k) {
                   gDz[3 * e + k] = T(r[GDZ + k]);
                   gcol[3 * e + k] = T(r[GF + k]);
                   gn[3 * e + k] = T(r[GF + 3 + k]);
                 }
                 gc[2 * e] = T(r[GC]);
                 gc[2 * e + 1] = T(r[GC + 1]);
                 gop[e] = T(r[GOP]);
               });
  return g;
}

}  // namespace
}  // namespace c2d

Grads2D composite2d_backward(const Surfels2D& s, const TileLists& lists, const Raster& raster, const Composite2D& fwd,
                             const at::Tensor& g_rgb, const at::Tensor& g_normal, const at::Tensor& g_alpha,
                             const at::Tensor& g_depth, const at::Tensor& g_median,
                             const at::Tensor& g_distortion, bool geometry) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  const std::vector<at::Tensor> og{g_rgb, g_normal, g_alpha, g_depth, g_median, g_distortion};
  Grads2D g;
  AT_DISPATCH_FLOATING_TYPES(s.colors.scalar_type(), "composite2d_backward", [&] {
    g = c2d::backward_impl<scalar_t>(s, lists, gr, fwd, og, geometry);
  });
  return g;
}

}  // namespace arcsem
