// Fused CPU compositing of 2-D Gaussian surfels (2DGS) over tiles: what the forward (composite2d.cpp) and the
// backward pass (composite2d_backward.cpp) share.
//
// Per (camera, splat) entry s the PyTorch side supplies:
//   H[s]  : 9 values, rows Tu, Tv, Tw of the splat-to-pixel homography; for pixel (x, y)
//           k = x Tw - Tu, l = y Tw - Tv, p = k x l, (u, v) = (p.x / p.z, p.y / p.z)
//   Dz[s] : 3 values, camera-z row of the splat: depth at (u, v) = u Dz.x + v Dz.y + Dz.z
//           (for a pinhole camera Dz = Tw; an orthographic camera has constant w, hence the extra row)
//   c[s]  : projected centre (pixels), for the low-pass rho2d = lp |pixel - c|^2 (lp = 1 / sigma^2; official 2)
//   opacity, features (colour, normal)
// Per camera, the normalised depth of the distortion loss is m = m0 + m1 z + m2 / z.
// Rules (official 2DGS): rho = min(rho3d, rho2d); depth = hit depth if rho3d <= rho2d else centre depth;
// skip depth < near, alpha < 1/255; alpha <= 0.99; stop before T would fall below 1e-4;
// median depth = depth of the last splat composited while T > 0.5.
// The distortion sum_ij w_i w_j (m_i - m_j)^2 is shift-invariant; m is shifted per pixel by the first
// composited splat's m to avoid the cancellation of m^2 A + M2 - 2 m M1 in float32 (as the PyTorch path).
//
// p = k x l expands to p = x a + y b + c with the adjugate columns a = Tv x Tw, b = Tw x Tu, c = Tu x Tv. A pair
// keeps them in its tile's pixel frame (c' = c + x0 a + y0 b, computed in double), so a float evaluation near
// the tile does not lose digits to large pixel coordinates. Tiles, lanes, the per-pair work list and the
// per-entry gradient sums work as in composite3d.cpp.
#pragma once
#include <cmath>
#include <vector>

#include "api.h"
#include "common.h"

namespace arcsem {
namespace c2d {


constexpr int K2 = 6;  // composited features: rgb, normal
// gradient row of a pair: adjugate columns a, b, c (9), Dz (3), centre (2), opacity, features
constexpr int GA = 0, GDZ = 9, GC = 12, GOP = 14, GF = 15, D2 = GF + K2;

template <typename T>
struct Pair2 {
  T a[3], b[3], c[3], dz[3], cx, cy, op, f[K2];  // adjugate in the tile frame, depth row, centre - origin, ...
  int32_t x0, x1, y0, y1;                         // pixel box clipped to the tile (local, inclusive)
  uint32_t rows;  // set by the forward: bit y where some live pixel of tile row y (y < 32) drew the pair
};

// whether the forward drew a pair on row y (rows past 32 are not recorded: assumed yes); the backward skips the others
inline bool composited_row(uint32_t rows, int y) { return y >= 32 || ((rows >> y) & 1u); }

// What a lane (pixel) sees of a pair: intersection (u, v), low-pass offset, depth, Gaussian, alpha.
template <typename T>
struct Hit2 {
  T p0, p1, ip, u, v, dx, dy, z, g, alpha;
  bool use3d, ok;
};

template <typename T>
inline Hit2<T> eval2(const Pair2<T>& q, int lx, T py, T near, T lp) {
  Hit2<T> h;
  const T px = T(lx) + T(0.5);
  h.p0 = px * q.a[0] + py * q.b[0] + q.c[0];
  h.p1 = px * q.a[1] + py * q.b[1] + q.c[1];
  const T p2 = px * q.a[2] + py * q.b[2] + q.c[2];
  h.ip = p2 != T(0) ? T(1) / p2 : T(0);
  h.u = h.p0 * h.ip;
  h.v = h.p1 * h.ip;
  const T rho3d = h.u * h.u + h.v * h.v;
  h.dx = q.cx - px;
  h.dy = q.cy - py;
  const T rho2d = lp * (h.dx * h.dx + h.dy * h.dy);
  h.use3d = rho3d <= rho2d;
  h.z = h.use3d ? h.u * q.dz[0] + h.v * q.dz[1] + q.dz[2] : q.dz[2];
  const T power = T(-0.5) * (h.use3d ? rho3d : rho2d);
  h.g = vexp(power);
  h.alpha = std::min(T(kMaxAlpha), q.op * h.g);
  h.ok = (p2 != T(0)) & (lx >= q.x0) & (lx <= q.x1) & (h.z >= near) & (power <= T(0)) & (h.alpha >= T(kMinAlpha));
  return h;
}

// A pair evaluated on the kLanes pixels of a tile row (structure of arrays), so that a block whose lanes all miss
// is skipped before the compositing arithmetic (about a third of the blocks on a trained model).
template <typename T>
struct Lanes2 {
  alignas(64) T u[kLanes], v[kLanes], ip[kLanes], dx[kLanes], dy[kLanes], z[kLanes], g[kLanes], alpha[kLanes];
  alignas(64) int32_t use3d[kLanes], ok[kLanes];
  Hit2<T> operator[](int i) const {
    Hit2<T> h;
    h.u = u[i]; h.v = v[i]; h.ip = ip[i]; h.dx = dx[i]; h.dy = dy[i]; h.z = z[i]; h.g = g[i]; h.alpha = alpha[i];
    h.use3d = use3d[i] != 0; h.ok = ok[i] != 0;
    h.p0 = h.p1 = T(0);  // (not kept)
    return h;
  }
};

// q on the pixels (c + i, py), i < NL (<= kLanes); a lane is ok where eval2 says so and gate(i) holds (the
// forward: the pixel is live; the backward: the pixel composited this pair). Returns whether any lane is ok.
template <int NL, typename T, class Gate>
inline bool eval_lanes(const Pair2<T>& q, int c, T py, T near, T lp, const Gate& gate, Lanes2<T>& L) {
  int any = 0;
#pragma omp simd reduction(| : any)
  for (int i = 0; i < NL; ++i) {
    const Hit2<T> h = eval2(q, c + i, py, near, lp);
    const bool ok = h.ok & gate(i);
    L.u[i] = h.u; L.v[i] = h.v; L.ip[i] = h.ip; L.dx[i] = h.dx; L.dy[i] = h.dy; L.z[i] = h.z; L.g[i] = h.g;
    L.alpha[i] = h.alpha; L.use3d[i] = h.use3d; L.ok[i] = ok;
    any |= int(ok);
  }
  return any != 0;
}

template <typename T>
struct In2 {
  const T *H, *Dz, *c, *op, *col, *nrm, *mc, *bg;
  const int64_t *off, *ids, *box;
  T near, lp;
};

template <typename T>
In2<T> inputs(const Surfels2D& s, const TileLists& l) {
  for (auto* t : {&s.H, &s.Dz, &s.centres, &s.opacities, &s.colors, &s.normals, &s.mcoef}) check_cpu(*t, "composite2d input");
  for (auto* t : {&l.offsets, &l.ids, &l.box}) check_cpu(*t, "composite2d tile lists");
  TORCH_CHECK(s.colors.size(1) == 3 && s.normals.size(1) == 3, "composite2d: colors, normals must be [M, 3]");
  return In2<T>{s.H.data_ptr<T>(), s.Dz.data_ptr<T>(), s.centres.data_ptr<T>(), s.opacities.data_ptr<T>(),
                s.colors.data_ptr<T>(), s.normals.data_ptr<T>(), s.mcoef.data_ptr<T>(), grad_or_null<T>(s.background),
                l.offsets.data_ptr<int64_t>(), l.ids.data_ptr<int64_t>(), l.box.data_ptr<int64_t>(), T(s.near),
                T(s.lowpass)};
}

// What a pair needs of its entry, packed (2-3 cache lines instead of one or two in each of seven arrays: the
// entries of a tile come in depth order, scattered in memory): adjugate columns a, b, c (double), depth row,
// centre, opacity, features and the pixel box.
template <typename T>
struct Entry2 {
  double A[9];
  T dz[3], f[K2], cx, cy, op;
  int32_t box[4];
};

// the M entries' records, in parallel
template <typename T>
std::vector<Entry2<T>> pack_entries(const In2<T>& in, int64_t M) {
  std::vector<Entry2<T>> out(static_cast<size_t>(M));
  parallel_range(M, 4096, [&](int64_t b, int64_t e, int) {
    for (int64_t s = b; s < e; ++s) {
      Entry2<T>& r = out[size_t(s)];
      double H[9];
      for (int k = 0; k < 9; ++k) H[k] = double(in.H[9 * s + k]);
      cross(H + 3, H + 6, r.A);      // a = Tv x Tw
      cross(H + 6, H, r.A + 3);      // b = Tw x Tu
      cross(H, H + 3, r.A + 6);      // c = Tu x Tv
      for (int k = 0; k < 3; ++k) {
        r.dz[k] = in.Dz[3 * s + k];
        r.f[k] = in.col[3 * s + k];
        r.f[3 + k] = in.nrm[3 * s + k];
      }
      r.cx = in.c[2 * s];
      r.cy = in.c[2 * s + 1];
      r.op = in.op[s];
      for (int k = 0; k < 4; ++k)  // (clamped: only the part inside the image is ever drawn)
        r.box[k] = int32_t(std::min<int64_t>(std::max<int64_t>(in.box[4 * s + k], -1), int64_t(1) << 30));
    }
  });
  return out;
}

// pairs [j0, j1) of tile ct into out (its first pair at out[0])
template <typename T>
void gather(const Entry2<T>* ent, const int64_t* ids, const Grid& gr, int64_t ct, int64_t j0, int64_t j1,
            Pair2<T>* out) {
  const int64_t x0 = gr.x0(ct), y0 = gr.y0(ct), nx = gr.nx(ct), ny = gr.ny(ct);
  for (int64_t j = j0; j < j1; ++j) {
    if (j + 4 < j1) {  // ask for the entry 4 pairs ahead
      const char* a = reinterpret_cast<const char*>(ent + ids[j + 4]);
      for (int k = 0; k < int(sizeof(Entry2<T>)); k += 64) __builtin_prefetch(a + k);
      __builtin_prefetch(a + sizeof(Entry2<T>) - 1);
    }
    const Entry2<T>& e = ent[ids[j]];
    Pair2<T>& q = out[j];
    for (int k = 0; k < 3; ++k) {
      q.a[k] = T(e.A[k]);
      q.b[k] = T(e.A[3 + k]);
      q.c[k] = T(e.A[6 + k] + double(x0) * e.A[k] + double(y0) * e.A[3 + k]);
      q.dz[k] = e.dz[k];
    }
    for (int k = 0; k < K2; ++k) q.f[k] = e.f[k];
    q.cx = e.cx - T(x0);
    q.cy = e.cy - T(y0);
    q.op = e.op;
    q.x0 = std::max<int32_t>(e.box[0] - int32_t(x0), 0); q.x1 = std::min<int32_t>(e.box[1] - int32_t(x0), int32_t(nx - 1));
    q.y0 = std::max<int32_t>(e.box[2] - int32_t(y0), 0); q.y1 = std::min<int32_t>(e.box[3] - int32_t(y0), int32_t(ny - 1));
  }
}

// Per-tile pixel state, lane-major as in composite3d.cpp (fields used by the forward or the backward pass).
template <typename T>
struct Tile2 {
  int stride = 0;
  size_t np = 0;
  // forward: transmittance, live flag, sum w, features, sum w z, m1, m2, distortion, first m, median depth
  // backward: transmittance, S, T_final, m1, m2, first m, feature / alpha / depth / median / distortion grads
  std::vector<T> tr, live, wsum, acc, wz, m1, m2, dist, mref, med, s, tf, go, ga, gd, gm, gdis;
  std::vector<int32_t> last, medi;
  std::vector<int> row_live;
  void reset(int64_t tile) {
    stride = int((tile + kLanes - 1) / kLanes * kLanes);
    np = size_t(stride) * size_t(tile);
    for (auto* v : {&tr, &live, &wsum, &wz, &m1, &m2, &dist, &mref, &med, &s, &tf, &ga, &gd, &gm, &gdis})
      v->assign(np, T(0));
    acc.assign(np * K2, T(0));
    go.assign(np * K2, T(0));
    last.assign(np, -1);
    medi.assign(np, -1);
    row_live.assign(size_t(tile), 0);
  }
  // component k of the K2-vectors (acc, go) of pixel (ly, lx) is at vec(ly, lx) + k * kLanes (blocks of kLanes pixels)
  size_t vec(int ly, int lx) const { return size_t(ly * stride + lx / kLanes * kLanes) * K2 + lx % kLanes; }
};

}  // namespace c2d
}  // namespace arcsem
