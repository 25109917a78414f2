// Fused CPU compositing of 2-D Gaussian surfels (2DGS) over tiles: forward and backward.
//
// Per (camera, splat) entry s the PyTorch side supplies:
//   H[s]  : 9 values, rows Tu, Tv, Tw of the splat-to-pixel homography; for pixel (x, y)
//           k = x Tw - Tu, l = y Tw - Tv, p = k x l, (u, v) = (p.x / p.z, p.y / p.z)
//   Dz[s] : 3 values, camera-z row of the splat: depth at (u, v) = u Dz.x + v Dz.y + Dz.z
//           (for a pinhole camera Dz = Tw; an orthographic camera has constant w, hence the extra row)
//   c[s]  : projected centre (pixels), for the low-pass rho2d = lp |pixel - c|^2 (lp = 1 / sigma^2; official 2)
//   opacity, features (colour, normal, ...)
// Per camera, the normalised depth of the distortion loss is m = m0 + m1 z + m2 / z.
// Rules (official 2DGS): rho = min(rho3d, rho2d); depth = hit depth if rho3d <= rho2d else centre depth;
// skip depth < near, alpha < 1/255; alpha <= 0.99; stop before T would fall below 1e-4;
// median depth = depth of the last splat composited while T > 0.5.
// The distortion sum_ij w_i w_j (m_i - m_j)^2 is shift-invariant; m is shifted per pixel by the first
// composited splat's m to avoid the cancellation of m^2 A + M2 - 2 m M1 in float32 (as the PyTorch path).
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <cmath>
#include <vector>

#include "common.h"

namespace {

using arcsem::Grid;
using arcsem::kMaxAlpha;
using arcsem::kMinAlpha;
using arcsem::kMinT;

// Per-pixel geometry is evaluated in double whatever the storage type (float32 accuracy of depth).
struct Hit {
  double p[3], u, v, dx, dy, rho3d, rho2d, z, g, alpha;
  bool use3d;
};

// One pair of a tile, gathered once per tile (contiguous, converted to double): the pixels of the tile
// then read it from cache instead of chasing ids -> splat arrays.
struct Surfel {
  double H[9], A[9], Dz[3], c[2], op;  // A: adjugate columns a = Tv x Tw, b = Tw x Tu, c = Tu x Tv
  int64_t x0, x1, y0, y1, s;
};

inline bool eval_surfel(const Surfel& q, double px, double py, double near, double lp, Hit& h) {
  // p = k x l with k = px Tw - Tu, l = py Tw - Tv, expanded: p = px a + py b + c (bilinear in the pixel)
  for (int j = 0; j < 3; ++j) h.p[j] = px * q.A[j] + py * q.A[3 + j] + q.A[6 + j];
  if (h.p[2] == 0.0) return false;
  h.u = h.p[0] / h.p[2];
  h.v = h.p[1] / h.p[2];
  h.rho3d = h.u * h.u + h.v * h.v;
  h.dx = q.c[0] - px;
  h.dy = q.c[1] - py;
  h.rho2d = lp * (h.dx * h.dx + h.dy * h.dy);
  h.use3d = h.rho3d <= h.rho2d;
  h.z = h.use3d ? h.u * q.Dz[0] + h.v * q.Dz[1] + q.Dz[2] : q.Dz[2];
  if (h.z < near) return false;
  const double power = -0.5 * (h.use3d ? h.rho3d : h.rho2d);
  if (power > 0.0) return false;
  h.g = std::exp(power);
  h.alpha = std::min(kMaxAlpha, q.op * h.g);
  return h.alpha >= kMinAlpha;
}

template <typename T>
struct Ptrs {  // inputs
  const T *H, *Dz, *c, *op, *f, *mc;
  const int64_t *off, *ids, *box;
  int64_t K;
  T near;
  double lp;  // low-pass filter 1 / sigma^2 (pixels^-2)
};

// the tile's pairs [off[ct], off[ct+1]) as Surfels and features [n * K], bucketed by row (local indices)
template <typename T>
struct TileData {
  std::vector<Surfel> sf;
  std::vector<double> f;
  std::vector<std::vector<arcsem::RowEntry>> rows;
  void gather(const Ptrs<T>& in, int64_t start, int64_t end, int64_t y0, int64_t ny) {
    const int64_t n = end - start;
    sf.resize(n);
    f.resize(n * in.K);
    for (int64_t j = 0; j < n; ++j) {
      const int64_t s = in.ids[start + j];
      Surfel& q = sf[j];
      for (int k = 0; k < 9; ++k) q.H[k] = double(in.H[9 * s + k]);
      arcsem::cross(q.H + 3, q.H + 6, q.A);      // a = Tv x Tw
      arcsem::cross(q.H + 6, q.H, q.A + 3);      // b = Tw x Tu
      arcsem::cross(q.H, q.H + 3, q.A + 6);      // c = Tu x Tv
      for (int k = 0; k < 3; ++k) q.Dz[k] = double(in.Dz[3 * s + k]);
      q.c[0] = double(in.c[2 * s]);
      q.c[1] = double(in.c[2 * s + 1]);
      q.op = double(in.op[s]);
      const int64_t* b = in.box + 4 * s;
      q.x0 = b[0]; q.x1 = b[1]; q.y0 = b[2]; q.y1 = b[3]; q.s = s;
      for (int64_t k = 0; k < in.K; ++k) f[j * in.K + k] = double(in.f[s * in.K + k]);
    }
    arcsem::bucket_rows_local(n, [&](int64_t j) { return &sf[j].x0; }, y0, ny, rows);
  }
};

template <typename T>
void forward_impl(const Grid& gr, const Ptrs<T>& in, T* out, T* tf, T* aout, T* dsum, T* med, T* dist, T* m1o,
                  T* m2o, T* mref, int32_t* last, int32_t* medi) {
  std::vector<TileData<T>> tds(at::get_num_threads());
  arcsem::for_each_tile(gr.C * gr.tiles(), [&](int64_t ct) {
    TileData<T>& td = tds[at::get_thread_num()];
    std::vector<double> acc(in.K);  // per-pixel sums and transmittance in double, whatever T is
    Hit h;
    const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct), start = in.off[ct];
    const T* mc = in.mc + 3 * c;
    td.gather(in, start, in.off[ct + 1], y0, gr.ny(ct));
    for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
      const auto& row = td.rows[y - y0];
      for (int64_t x = x0; x < x0 + gr.nx(ct); ++x) {
        const double px = x + 0.5, py = y + 0.5;
        std::fill(acc.begin(), acc.end(), 0.0);
        double Tr = 1, D = 0, M1 = 0, M2 = 0, dis = 0, m0 = 0;
        T md = 0;
        bool first = true;
        int32_t lastc = -1, mi = -1;
        for (const arcsem::RowEntry& e : row) {
          if (x < e.x0 || x > e.x1) continue;
          const int32_t j = e.j;
          const Surfel& q = td.sf[j];
          if (!eval_surfel(q, px, py, double(in.near), in.lp, h)) continue;
          const double next = Tr * (1.0 - h.alpha);
          if (next < kMinT) break;
          const double w = h.alpha * Tr;
          const double m_abs = double(mc[0]) + double(mc[1]) * h.z + double(mc[2]) / h.z;
          if (first) { m0 = m_abs; first = false; }
          const double m = m_abs - m0;
          dis += (m * m * (1.0 - Tr) + M2 - 2.0 * m * M1) * w;
          D += h.z * w;
          M1 += m * w;
          M2 += m * m * w;
          if (Tr > 0.5) { md = T(h.z); mi = int32_t(start + j); }
          const double* fj = td.f.data() + j * in.K;
          for (int64_t k = 0; k < in.K; ++k) acc[k] += w * fj[k];
          Tr = next;
          lastc = int32_t(start + j);
        }
        const int64_t pix = (c * gr.H + y) * gr.W + x;
        for (int64_t k = 0; k < in.K; ++k) out[pix * in.K + k] = T(acc[k]);
        tf[pix] = T(Tr); aout[pix] = T(1.0 - Tr); dsum[pix] = T(D); med[pix] = md; dist[pix] = T(dis); m1o[pix] = T(M1); m2o[pix] = T(M2);
        mref[pix] = T(m0);
        last[pix] = lastc; medi[pix] = mi;
      }
    }
  });
}

// gradient of a scalar function of (u, v) back to the adjugate columns a, b, c (adds into gA[9])
inline void backprop_uv(const Hit& h, double gu, double gv, double px, double py, double* gA) {
  const double gp[3] = {gu / h.p[2], gv / h.p[2], -(gu * h.u + gv * h.v) / h.p[2]};
  for (int j = 0; j < 3; ++j) {
    gA[j] += px * gp[j];
    gA[3 + j] += py * gp[j];
    gA[6 + j] += gp[j];
  }
}

// a = Tv x Tw, b = Tw x Tu, c = Tu x Tv: gradients of (a, b, c) -> of the rows Tu, Tv, Tw (in place, gAH[9])
inline void adjugate_to_rows(const double* H, double* gAH) {
  const double *Tu = H, *Tv = H + 3, *Tw = H + 6, *ga = gAH, *gb = gAH + 3, *gc = gAH + 6;
  double gH[9] = {0}, t[3];
  auto add = [&](int row, const double* x, const double* y) {  // gH[row] += x cross y
    arcsem::cross(x, y, t);
    for (int j = 0; j < 3; ++j) gH[3 * row + j] += t[j];
  };
  add(1, Tw, ga); add(2, ga, Tv);  // g.(u x v): d/du = v x g, d/dv = g x u
  add(2, Tu, gb); add(0, gb, Tw);
  add(0, Tv, gc); add(1, gc, Tu);
  std::copy(gH, gH + 9, gAH);
}

struct Grads {  // offsets in the per-entry gradient row
  static constexpr int H = 0, Dz = 9, c = 12, op = 14, f = 15;
};

template <typename T>
void backward_impl(const Grid& gr, const Ptrs<T>& in, const T* tf, const T* m1o, const T* m2o, const T* mref,
                   const int32_t* last,
                   const int32_t* medi, const T* g_out, const T* g_alpha, const T* g_dsum, const T* g_med,
                   const T* g_dist, int64_t M, T* gH, T* gDz, T* gc, T* gop, T* gf) {
  const int64_t D = Grads::f + in.K;
  const int nth = at::get_num_threads();
  std::vector<std::vector<double>> bufs(nth);  // per-thread [M, D] sums (double)
  std::vector<TileData<T>> tds(nth);
  arcsem::for_each_tile(gr.C * gr.tiles(), [&](int64_t ct) {
    const int tid = at::get_thread_num();
    auto& buf = bufs[tid];
    if (buf.empty()) buf.assign(M * D, 0.0);
    TileData<T>& td = tds[tid];
    Hit h;
    const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct), start = in.off[ct];
    const T* mc = in.mc + 3 * c;
    td.gather(in, start, in.off[ct + 1], y0, gr.ny(ct));
    std::vector<double> lg(td.sf.size() * D, 0.0);  // this tile's gradients per local pair
    for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
      const auto& row = td.rows[y - y0];
      for (int64_t x = x0; x < x0 + gr.nx(ct); ++x) {
        const int64_t pix = (c * gr.H + y) * gr.W + x;
        const double px = x + 0.5, py = y + 0.5;
        const double Tf = tf[pix], Wt = 1.0 - Tf, M1t = m1o[pix], M2t = m2o[pix];
        const T* go = g_out + pix * in.K;
        const double ga = g_alpha[pix], gd = g_dsum[pix], gm = g_med[pix], gdis = g_dist[pix];
        const int64_t jmed = int64_t(medi[pix]) - start;
        double Tr = Tf, S = 0;
        // back to front from the last composited pair (row is in pair order)
        for (auto it = arcsem::row_end(row, int64_t(last[pix]) - start); it != row.begin();) {
          const arcsem::RowEntry& e = *--it;
          if (x < e.x0 || x > e.x1) continue;
          const int32_t j = e.j;
          const Surfel& q = td.sf[j];
          if (!eval_surfel(q, px, py, double(in.near), in.lp, h)) continue;
          const double inv = 1.0 / (1.0 - h.alpha), Ti = Tr * inv, w = h.alpha * Ti;
          const double m = double(mc[0]) + double(mc[1]) * h.z + double(mc[2]) / h.z - double(mref[pix]);
          const double dm_dz = double(mc[1]) - double(mc[2]) / (double(h.z) * h.z);
          double* gb = lg.data() + j * D;
          const double* fj = td.f.data() + j * in.K;
          // dL/dw_i: every output is a sum over w_i of a per-splat value
          double gw = ga + gd * h.z + gdis * (m * m * Wt - 2.0 * m * M1t + M2t);
          for (int64_t k = 0; k < in.K; ++k) {
            gw += double(go[k]) * fj[k];
            gb[Grads::f + k] += w * go[k];
          }
          const double gz = w * gd + gdis * 2.0 * w * (m * Wt - M1t) * dm_dz + (jmed == j ? gm : 0.0);
          const double dalpha = gw * Ti - S * inv;
          S += gw * w;
          Tr = Ti;
          double dpow = 0;
          if (q.op * h.g <= kMaxAlpha) {
            gb[Grads::op] += dalpha * h.g;
            dpow = dalpha * q.op * h.g;
          }
          if (h.use3d) {  // power = -0.5 (u^2 + v^2); z = u Dz.x + v Dz.y + Dz.z
            gb[Grads::Dz] += gz * h.u;
            gb[Grads::Dz + 1] += gz * h.v;
            gb[Grads::Dz + 2] += gz;
            backprop_uv(h, -dpow * h.u + gz * q.Dz[0], -dpow * h.v + gz * q.Dz[1], px, py, gb + Grads::H);
          } else {  // power = -lp (dx^2 + dy^2) / 2 with d = centre - pixel; z = Dz.z
            gb[Grads::Dz + 2] += gz;
            gb[Grads::c] += dpow * -in.lp * h.dx;
            gb[Grads::c + 1] += dpow * -in.lp * h.dy;
          }
        }
      }
    }
    for (size_t j = 0; j < td.sf.size(); ++j) {
      double* dst = buf.data() + td.sf[j].s * D;
      double* src = lg.data() + j * D;
      adjugate_to_rows(td.sf[j].H, src + Grads::H);
      for (int64_t k = 0; k < D; ++k) dst[k] += src[k];
    }
  });
  std::vector<double> g(D);
  for (int64_t s = 0; s < M; ++s) {
    arcsem::sum_thread_rows(bufs, s, D, g.data());
    for (int j = 0; j < 9; ++j) gH[9 * s + j] = T(g[Grads::H + j]);
    for (int j = 0; j < 3; ++j) gDz[3 * s + j] = T(g[Grads::Dz + j]);
    gc[2 * s] = T(g[Grads::c]);
    gc[2 * s + 1] = T(g[Grads::c + 1]);
    gop[s] = T(g[Grads::op]);
    for (int64_t k = 0; k < in.K; ++k) gf[s * in.K + k] = T(g[Grads::f + k]);
  }
}

template <typename T>
Ptrs<T> ptrs(const torch::Tensor& H, const torch::Tensor& Dz, const torch::Tensor& c, const torch::Tensor& op,
             const torch::Tensor& f, const torch::Tensor& mc, const torch::Tensor& off, const torch::Tensor& ids,
             const torch::Tensor& box, double near, double lp) {
  for (auto* t : {&H, &Dz, &c, &op, &f, &mc, &off, &ids, &box})
    TORCH_CHECK(t->is_contiguous() && t->device().is_cpu(), "composite2d: inputs must be contiguous CPU tensors");
  return Ptrs<T>{H.data_ptr<T>(), Dz.data_ptr<T>(), c.data_ptr<T>(), op.data_ptr<T>(), f.data_ptr<T>(),
                 mc.data_ptr<T>(), off.data_ptr<int64_t>(), ids.data_ptr<int64_t>(), box.data_ptr<int64_t>(), f.size(1),
                 T(near), lp};
}

}  // namespace

// a gradient tensor's data, or null when autograd passed none (the output was not used)
template <typename T>
const T* grad_or_null(const torch::Tensor& g) { return g.defined() && g.numel() ? g.data_ptr<T>() : nullptr; }

// colors [M, 3] and normals [M, 3] (features f = both), bg [3] or empty ->
// rgb, normal [C, H, W, 3], alpha, depth, median depth, distortion [C, H, W, 1]; then, for the backward:
// f, transmittance, m1, m2, mref, last, medi, sum w z
std::vector<torch::Tensor> forward2d(torch::Tensor H, torch::Tensor Dz, torch::Tensor c, torch::Tensor op,
                                     torch::Tensor colors, torch::Tensor normals, torch::Tensor mc, torch::Tensor off,
                                     torch::Tensor ids, torch::Tensor box, torch::Tensor bg, double near, double lp,
                                     int64_t C, int64_t Hh, int64_t W, int64_t tile) {
  const Grid gr = arcsem::make_grid(C, Hh, W, tile);
  TORCH_CHECK(off.numel() == C * gr.tiles() + 1, "composite2d: tile offsets must have C*tiles+1 entries");
  TORCH_CHECK(colors.size(1) == 3 && colors.is_contiguous() && normals.is_contiguous(), "composite2d: colors [M, 3]");
  const int64_t M = colors.size(0), K = 3 + normals.size(1), P = C * Hh * W;
  auto o = colors.options();
  auto f = torch::empty({M, K}, o), out = torch::empty({C, Hh, W, K}, o);
  auto tf = torch::empty({C, Hh, W, 1}, o), alpha = torch::empty_like(tf), dsum = torch::empty_like(tf),
       med = torch::empty_like(tf), dist = torch::empty_like(tf), m1 = torch::empty_like(tf), m2 = torch::empty_like(tf),
       mref = torch::empty_like(tf), depth = torch::empty_like(tf);
  auto rgb = torch::empty({C, Hh, W, 3}, o), extra = torch::empty({C, Hh, W, K - 3}, o);
  auto last = torch::empty({C, Hh, W}, o.dtype(torch::kInt32)), medi = torch::empty_like(last);
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "forward2d", [&] {
    arcsem::concat_rows(colors.data_ptr<scalar_t>(), 3, normals.data_ptr<scalar_t>(), K - 3, M, f.data_ptr<scalar_t>());
    forward_impl<scalar_t>(gr, ptrs<scalar_t>(H, Dz, c, op, f, mc, off, ids, box, near, lp), out.data_ptr<scalar_t>(),
                           tf.data_ptr<scalar_t>(), alpha.data_ptr<scalar_t>(), dsum.data_ptr<scalar_t>(), med.data_ptr<scalar_t>(),
                           dist.data_ptr<scalar_t>(), m1.data_ptr<scalar_t>(), m2.data_ptr<scalar_t>(),
                           mref.data_ptr<scalar_t>(), last.data_ptr<int32_t>(), medi.data_ptr<int32_t>());
    arcsem::finish_outputs<scalar_t>(P, K, out.data_ptr<scalar_t>(), alpha.data_ptr<scalar_t>(), dsum.data_ptr<scalar_t>(), 1,
                                     grad_or_null<scalar_t>(bg), rgb.data_ptr<scalar_t>(), extra.data_ptr<scalar_t>(),
                                     depth.data_ptr<scalar_t>());
  });
  return {rgb, extra, alpha, depth, med, dist, f, tf, m1, m2, mref, last, medi, dsum};
}

// -> g_H, g_Dz, g_centres, g_opacities, g_colors, g_normals (undefined / empty output gradients are zero)
std::vector<torch::Tensor> backward2d(torch::Tensor H, torch::Tensor Dz, torch::Tensor c, torch::Tensor op,
                                      torch::Tensor f, torch::Tensor mc, torch::Tensor off, torch::Tensor ids,
                                      torch::Tensor box, torch::Tensor bg, double near, double lp, int64_t C, int64_t Hh,
                                      int64_t W, int64_t tile, torch::Tensor tf, torch::Tensor m1, torch::Tensor m2,
                                      torch::Tensor mref, torch::Tensor last, torch::Tensor medi, torch::Tensor alpha,
                                      torch::Tensor dsum, torch::Tensor g_rgb, torch::Tensor g_extra,
                                      torch::Tensor g_alpha, torch::Tensor g_depth, torch::Tensor g_med,
                                      torch::Tensor g_dist) {
  const Grid gr = arcsem::make_grid(C, Hh, W, tile);
  const int64_t M = f.size(0), K = f.size(1), P = C * Hh * W;
  auto gH = torch::empty_like(H), gDz = torch::empty_like(Dz), gc = torch::empty_like(c), gop = torch::empty_like(op),
       gf = torch::empty_like(f);
  AT_DISPATCH_FLOATING_TYPES(f.scalar_type(), "backward2d", [&] {
    std::vector<scalar_t> go(P * K), ga(P), gd(P), zero(P, scalar_t(0));
    arcsem::finish_backward<scalar_t>(P, K, alpha.data_ptr<scalar_t>(), dsum.data_ptr<scalar_t>(), 1,
                                      grad_or_null<scalar_t>(bg), grad_or_null<scalar_t>(g_rgb),
                                      grad_or_null<scalar_t>(g_extra), grad_or_null<scalar_t>(g_alpha),
                                      grad_or_null<scalar_t>(g_depth), go.data(), ga.data(), gd.data(), 1);
    const scalar_t* gm = grad_or_null<scalar_t>(g_med);
    const scalar_t* gdi = grad_or_null<scalar_t>(g_dist);
    backward_impl<scalar_t>(gr, ptrs<scalar_t>(H, Dz, c, op, f, mc, off, ids, box, near, lp), tf.data_ptr<scalar_t>(),
                            m1.data_ptr<scalar_t>(), m2.data_ptr<scalar_t>(), mref.data_ptr<scalar_t>(),
                            last.data_ptr<int32_t>(), medi.data_ptr<int32_t>(), go.data(), ga.data(), gd.data(),
                            gm ? gm : zero.data(), gdi ? gdi : zero.data(), M, gH.data_ptr<scalar_t>(),
                            gDz.data_ptr<scalar_t>(), gc.data_ptr<scalar_t>(), gop.data_ptr<scalar_t>(),
                            gf.data_ptr<scalar_t>());
  });
  return {gH, gDz, gc, gop, arcsem::split_cols(gf, 3), arcsem::split_cols(gf, 3, K - 3)};
}
