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

// evaluated in double whatever the storage type
template <typename T>
inline bool eval_splat(const T* m2, const T* con, T op, double px, double py, double& dx, double& dy, double& g,
                       double& alpha) {
  dx = px - double(m2[0]);
  dy = py - double(m2[1]);
  const double power = -0.5 * (double(con[0]) * dx * dx + double(con[2]) * dy * dy) - double(con[1]) * dx * dy;
  if (power > 0.0) return false;
  g = std::exp(power);
  alpha = std::min(kMaxAlpha, double(op) * g);
  return alpha >= kMinAlpha;
}

template <typename T>
void forward_impl(const Grid& gr, const T* means2d, const T* conics, const T* opac, const T* feats, int64_t K,
                  const int64_t* offsets, const int64_t* ids, const int64_t* box, T* out, T* t_final, T* alpha_out,
                  int32_t* last) {
  at::parallel_for(0, gr.C * gr.tiles(), 1, [&](int64_t b, int64_t e) {
    std::vector<double> acc(K);  // per-pixel sums and transmittance in double, whatever T is
    std::vector<std::vector<int64_t>> rows;
    for (int64_t ct = b; ct < e; ++ct) {
      const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct);
      arcsem::bucket_rows(ids, box, offsets[ct], offsets[ct + 1], y0, gr.ny(ct), rows);
      for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
        const auto& row = rows[y - y0];
        for (int64_t x = x0; x < x0 + gr.nx(ct); ++x) {
          const double px = x + 0.5, py = y + 0.5;
          std::fill(acc.begin(), acc.end(), 0.0);
          double Tr = 1.0;
          int32_t lastc = -1;
          for (const int64_t i : row) {
            const int64_t s = ids[i];
            if (arcsem::outside_x(box, s, x)) continue;
            double dx, dy, g, alpha;
            if (!eval_splat(means2d + 2 * s, conics + 3 * s, opac[s], px, py, dx, dy, g, alpha)) continue;
            const double next = Tr * (1.0 - alpha);
            if (next < kMinT) break;
            const double w = alpha * Tr;
            for (int64_t k = 0; k < K; ++k) acc[k] += w * feats[s * K + k];
            Tr = next;
            lastc = int32_t(i);
          }
          const int64_t pix = (c * gr.H + y) * gr.W + x;
          for (int64_t k = 0; k < K; ++k) out[pix * K + k] = T(acc[k]);
          t_final[pix] = T(Tr);
          alpha_out[pix] = T(1.0 - Tr);  // from the double transmittance: no cancellation for faint pixels
          last[pix] = lastc;
        }
      }
    }
  });
}

template <typename T>
void backward_impl(const Grid& gr, const T* means2d, const T* conics, const T* opac, const T* feats, int64_t K,
                   const int64_t* offsets, const int64_t* ids, const int64_t* box, const T* t_final, const int32_t* last,
                   const T* g_out, const T* g_alpha, T* g_means2d, T* g_conics, T* g_opac, T* g_feats,
                   int64_t M) {
  const int nthreads = at::get_num_threads();
  // per-thread buffers: [thread][M][2 + 3 + 1 + K]
  const int64_t D = 6 + K;
  std::vector<std::vector<T>> bufs(nthreads);
  at::parallel_for(0, gr.C * gr.tiles(), 1, [&](int64_t b, int64_t e) {
    auto& buf = bufs[at::get_thread_num()];
    if (buf.empty()) buf.assign(M * D, T(0));
    std::vector<double> S(K);
    std::vector<std::vector<int64_t>> rows;
    for (int64_t ct = b; ct < e; ++ct) {
      const int64_t c = ct / gr.tiles(), x0 = gr.x0(ct), y0 = gr.y0(ct);
      arcsem::bucket_rows(ids, box, offsets[ct], offsets[ct + 1], y0, gr.ny(ct), rows);
      for (int64_t y = y0; y < y0 + gr.ny(ct); ++y) {
        const auto& row = rows[y - y0];
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
          for (auto it = std::upper_bound(row.begin(), row.end(), int64_t(last[pix])); it != row.begin();) {
            const int64_t s = ids[*--it];
            if (arcsem::outside_x(box, s, x)) continue;
            double dx, dy, g, alpha;
            if (!eval_splat(means2d + 2 * s, conics + 3 * s, opac[s], px, py, dx, dy, g, alpha)) continue;
            const double inv = 1.0 / (1.0 - alpha);
            const double Ti = Tr * inv;  // transmittance before splat i
            const double w = alpha * Ti;
            T* gb = buf.data() + s * D;
            double dalpha = ga * Tf * inv;
            for (int64_t k = 0; k < K; ++k) {
              const double f = feats[s * K + k];
              gb[6 + k] += T(w * go[k]);
              dalpha += go[k] * (Ti * f - S[k] * inv);
              S[k] += w * f;
            }
            Tr = Ti;
            if (double(opac[s]) * g > kMaxAlpha) continue;  // clamped: no gradient through alpha
            gb[5] += T(dalpha * g);                         // d alpha / d opacity
            const double dpow = dalpha * double(opac[s]) * g;  // d alpha / d power
            const T* con = conics + 3 * s;
            gb[0] += T(dpow * (double(con[0]) * dx + double(con[1]) * dy));  // d power / d mean = -(d / d dx)
            gb[1] += T(dpow * (double(con[1]) * dx + double(con[2]) * dy));
            gb[2] += T(dpow * -0.5 * dx * dx);
            gb[3] += T(dpow * (-dx * dy));
            gb[4] += T(dpow * -0.5 * dy * dy);
          }
        }
      }
    }
  });
  for (auto& buf : bufs) {
    if (buf.empty()) continue;
    for (int64_t s = 0; s < M; ++s) {
      const T* gb = buf.data() + s * D;
      g_means2d[2 * s] += gb[0];
      g_means2d[2 * s + 1] += gb[1];
      for (int j = 0; j < 3; ++j) g_conics[3 * s + j] += gb[2 + j];
      g_opac[s] += gb[5];
      for (int64_t k = 0; k < K; ++k) g_feats[s * K + k] += gb[6 + k];
    }
  }
}

void check(const torch::Tensor& t, const char* name, int64_t dim) {
  TORCH_CHECK(t.is_contiguous() && t.device().is_cpu(), name, " must be a contiguous CPU tensor");
  TORCH_CHECK(t.dim() == dim, name, " must have ", dim, " dims");
}

}  // namespace

std::vector<torch::Tensor> forward3d(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                     torch::Tensor feats, torch::Tensor offsets, torch::Tensor ids, torch::Tensor box,
                                     int64_t C, int64_t H, int64_t W, int64_t tile) {
  check(means2d, "means2d", 2); check(conics, "conics", 2); check(opac, "opacities", 1);
  check(feats, "features", 2); check(offsets, "tile offsets", 1); check(ids, "ids", 1); check(box, "pixel boxes", 2);
  const Grid gr = arcsem::make_grid(C, H, W, tile);
  TORCH_CHECK(offsets.numel() == C * gr.tiles() + 1, "tile offsets must have C*tiles+1 entries");
  const int64_t K = feats.size(1);
  auto out = torch::empty({C, H, W, K}, feats.options());
  auto tf = torch::empty({C, H, W}, feats.options()), alpha = torch::empty_like(tf);
  auto last = torch::empty({C, H, W}, feats.options().dtype(torch::kInt32));
  AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "forward3d", [&] {
    forward_impl<scalar_t>(gr, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                           opac.data_ptr<scalar_t>(), feats.data_ptr<scalar_t>(), K,
                           offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(), box.data_ptr<int64_t>(), out.data_ptr<scalar_t>(),
                           tf.data_ptr<scalar_t>(), alpha.data_ptr<scalar_t>(), last.data_ptr<int32_t>());
  });
  return {out, tf, alpha, last};
}

std::vector<torch::Tensor> backward3d(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                      torch::Tensor feats, torch::Tensor offsets, torch::Tensor ids,
                                      torch::Tensor box, torch::Tensor t_final, torch::Tensor last, torch::Tensor g_out,
                                      torch::Tensor g_alpha, int64_t C, int64_t H, int64_t W, int64_t tile) {
  const Grid gr = arcsem::make_grid(C, H, W, tile);
  const int64_t K = feats.size(1), M = feats.size(0);
  auto gm = torch::zeros_like(means2d), gc = torch::zeros_like(conics), go = torch::zeros_like(opac),
       gf = torch::zeros_like(feats);
  g_out = g_out.contiguous();
  g_alpha = g_alpha.contiguous();
  AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "backward3d", [&] {
    backward_impl<scalar_t>(gr, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                            opac.data_ptr<scalar_t>(), feats.data_ptr<scalar_t>(), K,
                            offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(), box.data_ptr<int64_t>(), t_final.data_ptr<scalar_t>(),
                            last.data_ptr<int32_t>(), g_out.data_ptr<scalar_t>(), g_alpha.data_ptr<scalar_t>(),
                            gm.data_ptr<scalar_t>(), gc.data_ptr<scalar_t>(), go.data_ptr<scalar_t>(),
                            gf.data_ptr<scalar_t>(), M);
  });
  return {gm, gc, go, gf};
}
