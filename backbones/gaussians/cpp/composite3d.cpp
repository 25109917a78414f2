// Fused CPU compositing of 3-D Gaussians (3DGS) over 16x16 tiles: forward and backward.
//
// The projection (EWA, conics, binning, depth sort) stays in PyTorch; these kernels replace only the
// per-pixel front-to-back loop, which is where a vectorised PyTorch compositor spends its time.
// Semantics equal the PyTorch reference path (backbones/gs3d/render.py) and the official rasteriser:
//   power = -0.5 (a dx^2 + c dy^2) - b dx dy; skip if power > 0
//   alpha = min(0.99, opacity exp(power)); skip if alpha < 1/255
//   stop before a splat whose composite would leave T < 1e-4
// Parallel over (camera, tile); gradients of splats shared by tiles go to per-thread buffers.
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

// One pair of a tile, gathered once per tile (contiguous, double): mean, conic, opacity, pixel box
struct Splat2 {
  double m[2], con[3], op;
  int64_t x0, x1, y0, y1, s;
};

template <typename T>
struct TileData {
  std::vector<Splat2> sp;
  std::vector<double> f;
  std::vector<std::vector<arcsem::RowEntry>> rows;
  void gather(const T* means2d, const T* conics, const T* opac, const T* feats, int64_t K, const int64_t* ids,
              const int64_t* box, int64_t start, int64_t end, int64_t y0, int64_t ny) {
    const int64_t n = end - start;
    sp.resize(n);
    f.resize(n * K);
    for (int64_t j = 0; j < n; ++j) {
      const int64_t s = ids[start + j];
      Splat2& q = sp[j];
      q.m[0] = means2d[2 * s]; q.m[1] = means2d[2 * s + 1];
      for (int k = 0; k < 3; ++k) q.con[k] = conics[3 * s + k];
      q.op = opac[s];
      const int64_t* b = box + 4 * s;
      q.x0 = b[0]; q.x1 = b[1]; q.y0 = b[2]; q.y1 = b[3]; q.s = s;
      for (int64_t k = 0; k < K; ++k) f[j * K + k] = feats[s * K + k];
    }
    arcsem::bucket_rows_local(n, [&](int64_t j) { return &sp[j].x0; }, y0, ny, rows);
  }
};

// evaluated in double whatever the storage type
inline bool eval_splat(const Splat2& q, double px, double py, double& dx, double& dy, double& g, double& alpha) {
  dx = px - q.m[0];
  dy = py - q.m[1];
  const double power = -0.5 * (q.con[0] * dx * dx + q.con[2] * dy * dy) - q.con[1] * dx * dy;
  if (power > 0.0) return false;
  g = std::exp(power);
  alpha = std::min(kMaxAlpha, q.op * g);
  return alpha >= kMinAlpha;
}

template <typename T>
void forward_impl(const Grid& gr, const T* means2d, const T* conics, const T* opac, const T* feats, int64_t K,
                  const int64_t* offsets, const int64_t* ids, const int64_t* box, T* out, T* t_final, T* alpha_out,
                  int32_t* last) {
  std::vector<TileData<T>> tds(at::get_num_threads());
  arcsem::for_each_tile(gr.C * gr.tiles(), [&](int64_t ct) {
    TileData<T>& td = tds[at::get_thread_num()];
    std::vector<double> acc(K);  // per-pixel sums and transmittance in double, whatever T is
    const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct), start = offsets[ct];
    td.gather(means2d, conics, opac, feats, K, ids, box, start, offsets[ct + 1], y0, gr.ny(ct));
    for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
      const auto& row = td.rows[y - y0];
      for (int64_t x = x0; x < x0 + gr.nx(ct); ++x) {
        const double px = x + 0.5, py = y + 0.5;
        std::fill(acc.begin(), acc.end(), 0.0);
        double Tr = 1.0;
        int32_t lastc = -1;
        for (const arcsem::RowEntry& e : row) {
          if (x < e.x0 || x > e.x1) continue;
          const int32_t j = e.j;
          const Splat2& q = td.sp[j];
          double dx, dy, g, alpha;
          if (!eval_splat(q, px, py, dx, dy, g, alpha)) continue;
          const double next = Tr * (1.0 - alpha);
          if (next < kMinT) break;
          const double w = alpha * Tr;
          const double* fj = td.f.data() + j * K;
          for (int64_t k = 0; k < K; ++k) acc[k] += w * fj[k];
          Tr = next;
          lastc = int32_t(start + j);
        }
        const int64_t pix = (c * gr.H + y) * gr.W + x;
        for (int64_t k = 0; k < K; ++k) out[pix * K + k] = T(acc[k]);
        t_final[pix] = T(Tr);
        alpha_out[pix] = T(1.0 - Tr);  // from the double transmittance: no cancellation for faint pixels
        last[pix] = lastc;
      }
    }
  });
}

template <typename T>
void backward_impl(const Grid& gr, const T* means2d, const T* conics, const T* opac, const T* feats, int64_t K,
                   const int64_t* offsets, const int64_t* ids, const int64_t* box, const T* t_final, const int32_t* last,
                   const T* g_out, const T* g_alpha, T* g_means2d, T* g_conics, T* g_opac, T* g_feats,
                   int64_t M) {
  const int nth = at::get_num_threads();
  const int64_t D = 6 + K;  // gradient row: mean (2), conic (3), opacity, features (K)
  std::vector<std::vector<double>> bufs(nth);  // per-thread [M, D] sums (double)
  std::vector<TileData<T>> tds(nth);
  arcsem::for_each_tile(gr.C * gr.tiles(), [&](int64_t ct) {
    const int tid = at::get_thread_num();
    auto& buf = bufs[tid];
    if (buf.empty()) buf.assign(M * D, 0.0);
    TileData<T>& td = tds[tid];
    std::vector<double> S(K);
    const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct), start = offsets[ct];
    td.gather(means2d, conics, opac, feats, K, ids, box, start, offsets[ct + 1], y0, gr.ny(ct));
    std::vector<double> lg(td.sp.size() * D, 0.0);  // this tile's gradients per local pair
    for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
      const auto& row = td.rows[y - y0];
      for (int64_t x = x0; x < x0 + gr.nx(ct); ++x) {
        const int64_t pix = (c * gr.H + y) * gr.W + x;
        const double px = x + 0.5, py = y + 0.5;
        const double Tf = t_final[pix];
        const T* go = g_out + pix * K;
        // alpha_out = 1 - T_final: dL/dalpha_i gets +g_alpha * T_final / (1 - alpha_i)
        const double ga = g_alpha[pix];
        std::fill(S.begin(), S.end(), 0.0);
        double Tr = Tf;
        // back to front from the last composited pair (row is in pair order)
        for (auto it = arcsem::row_end(row, int64_t(last[pix]) - start); it != row.begin();) {
          const arcsem::RowEntry& e = *--it;
          if (x < e.x0 || x > e.x1) continue;
          const int32_t j = e.j;
          const Splat2& q = td.sp[j];
          double dx, dy, g, alpha;
          if (!eval_splat(q, px, py, dx, dy, g, alpha)) continue;
          const double inv = 1.0 / (1.0 - alpha);
          const double Ti = Tr * inv;  // transmittance before splat i
          const double w = alpha * Ti;
          double* gb = lg.data() + j * D;
          const double* fj = td.f.data() + j * K;
          double dalpha = ga * Tf * inv;
          for (int64_t k = 0; k < K; ++k) {
            gb[6 + k] += w * go[k];
            dalpha += go[k] * (Ti * fj[k] - S[k] * inv);
            S[k] += w * fj[k];
          }
          Tr = Ti;
          if (q.op * g > kMaxAlpha) continue;  // clamped: no gradient through alpha
          gb[5] += dalpha * g;                 // d alpha / d opacity
          const double dpow = dalpha * q.op * g;  // d alpha / d power
          gb[0] += dpow * (q.con[0] * dx + q.con[1] * dy);  // d power / d mean = -(d / d dx)
          gb[1] += dpow * (q.con[1] * dx + q.con[2] * dy);
          gb[2] += dpow * -0.5 * dx * dx;
          gb[3] += dpow * (-dx * dy);
          gb[4] += dpow * -0.5 * dy * dy;
        }
      }
    }
    for (size_t j = 0; j < td.sp.size(); ++j) {
      double* dst = buf.data() + td.sp[j].s * D;
      const double* src = lg.data() + j * D;
      for (int64_t k = 0; k < D; ++k) dst[k] += src[k];
    }
  });
  std::vector<double> g(D);
  for (int64_t s = 0; s < M; ++s) {
    arcsem::sum_thread_rows(bufs, s, D, g.data());
    g_means2d[2 * s] = T(g[0]);
    g_means2d[2 * s + 1] = T(g[1]);
    for (int j = 0; j < 3; ++j) g_conics[3 * s + j] = T(g[2 + j]);
    g_opac[s] = T(g[5]);
    for (int64_t k = 0; k < K; ++k) g_feats[s * K + k] = T(g[6 + k]);
  }
}

void check(const torch::Tensor& t, const char* name, int64_t dim) {
  TORCH_CHECK(t.is_contiguous() && t.device().is_cpu(), name, " must be a contiguous CPU tensor");
  TORCH_CHECK(t.dim() == dim, name, " must have ", dim, " dims");
}

}  // namespace

template <typename T>
const T* grad_or_null(const torch::Tensor& g) { return g.defined() && g.numel() ? g.data_ptr<T>() : nullptr; }

// colors [M, 3], depth [M] (features f = both), bg [3] or empty -> rgb [C, H, W, 3], alpha, depth [C, H, W, 1];
// then, for the backward: f, transmittance, last, the sum w z
std::vector<torch::Tensor> forward3d(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                     torch::Tensor colors, torch::Tensor depth, torch::Tensor offsets, torch::Tensor ids,
                                     torch::Tensor box, torch::Tensor bg, int64_t C, int64_t H, int64_t W, int64_t tile) {
  check(means2d, "means2d", 2); check(conics, "conics", 2); check(opac, "opacities", 1); check(colors, "colors", 2);
  check(depth, "depth", 1); check(offsets, "tile offsets", 1); check(ids, "ids", 1); check(box, "pixel boxes", 2);
  const Grid gr = arcsem::make_grid(C, H, W, tile);
  TORCH_CHECK(offsets.numel() == C * gr.tiles() + 1, "tile offsets must have C*tiles+1 entries");
  const int64_t M = colors.size(0), K = 4, P = C * H * W;
  auto o = colors.options();
  auto f = torch::empty({M, K}, o), out = torch::empty({C, H, W, K}, o);
  auto tf = torch::empty({C, H, W, 1}, o), alpha = torch::empty_like(tf), dep = torch::empty_like(tf);
  auto rgb = torch::empty({C, H, W, 3}, o), extra = torch::empty({C, H, W, 1}, o);
  auto last = torch::empty({C, H, W}, o.dtype(torch::kInt32));
  AT_DISPATCH_FLOATING_TYPES(colors.scalar_type(), "forward3d", [&] {
    arcsem::concat_rows(colors.data_ptr<scalar_t>(), 3, depth.data_ptr<scalar_t>(), 1, M, f.data_ptr<scalar_t>());
    forward_impl<scalar_t>(gr, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                           opac.data_ptr<scalar_t>(), f.data_ptr<scalar_t>(), K,
                           offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(), box.data_ptr<int64_t>(), out.data_ptr<scalar_t>(),
                           tf.data_ptr<scalar_t>(), alpha.data_ptr<scalar_t>(), last.data_ptr<int32_t>());
    arcsem::finish_outputs<scalar_t>(P, K, out.data_ptr<scalar_t>(), alpha.data_ptr<scalar_t>(), out.data_ptr<scalar_t>() + 3,
                                     K, grad_or_null<scalar_t>(bg), rgb.data_ptr<scalar_t>(), extra.data_ptr<scalar_t>(),
                                     dep.data_ptr<scalar_t>());
  });
  return {rgb, alpha, dep, f, tf, last, extra};
}

// -> g_means2d, g_conics, g_opacities, g_colors, g_depth (undefined / empty output gradients are zero)
std::vector<torch::Tensor> backward3d(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                      torch::Tensor f, torch::Tensor offsets, torch::Tensor ids, torch::Tensor box,
                                      torch::Tensor bg, torch::Tensor t_final, torch::Tensor last, torch::Tensor alpha,
                                      torch::Tensor wz, torch::Tensor g_rgb, torch::Tensor g_alpha,
                                      torch::Tensor g_depth, int64_t C, int64_t H, int64_t W, int64_t tile) {
  const Grid gr = arcsem::make_grid(C, H, W, tile);
  const int64_t K = f.size(1), M = f.size(0), P = C * H * W;
  auto gm = torch::empty_like(means2d), gc = torch::empty_like(conics), go = torch::empty_like(opac),
       gf = torch::empty_like(f);
  AT_DISPATCH_FLOATING_TYPES(f.scalar_type(), "backward3d", [&] {
    std::vector<scalar_t> gout(P * K), ga(P);
    arcsem::finish_backward<scalar_t>(P, K, alpha.data_ptr<scalar_t>(), wz.data_ptr<scalar_t>(), 1,
                                      grad_or_null<scalar_t>(bg), grad_or_null<scalar_t>(g_rgb), nullptr,
                                      grad_or_null<scalar_t>(g_alpha), grad_or_null<scalar_t>(g_depth), gout.data(),
                                      ga.data(), gout.data() + 3, K);
    backward_impl<scalar_t>(gr, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                            opac.data_ptr<scalar_t>(), f.data_ptr<scalar_t>(), K,
                            offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(), box.data_ptr<int64_t>(), t_final.data_ptr<scalar_t>(),
                            last.data_ptr<int32_t>(), gout.data(), ga.data(),
                            gm.data_ptr<scalar_t>(), gc.data_ptr<scalar_t>(), go.data_ptr<scalar_t>(),
                            gf.data_ptr<scalar_t>(), M);
  });
  return {gm, gc, go, arcsem::split_cols(gf, 3), arcsem::split_cols(gf, 3, 1).view({M})};
}
