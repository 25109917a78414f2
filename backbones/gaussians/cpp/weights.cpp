// W^T g of a frozen geometry's compositing weights (weights.h): stage 2's colour gradient from the pixel-major record.
#include "api.h"
#include "common.h"

namespace arcsem {
namespace {

template <typename T>
void backward_impl(const ColourWeights& w, const Grid& gr, const at::Tensor& g, at::Tensor& out) {
  const int32_t *ptr = w.pix_ptr.data_ptr<int32_t>(), *pair = w.pix_pair.data_ptr<int32_t>();
  const T *__restrict wv = w.pix_w.data_ptr<T>(), *__restrict gv = g.data_ptr<T>();
  T* __restrict o = out.data_ptr<T>();
  parallel_chunks(gr.C * gr.tiles(), [&](int64_t ct, int) {
    const int64_t c = ct / gr.tiles();
    for (int64_t ly = 0; ly < gr.ny(ct); ++ly)
      for (int64_t lx = 0; lx < gr.nx(ct); ++lx) {
        const int64_t p = (c * gr.H + gr.y0(ct) + ly) * gr.W + gr.x0(ct) + lx;
        const T g0 = gv[3 * p], g1 = gv[3 * p + 1], g2 = gv[3 * p + 2];  // the pixel's gradient, for its whole row
        for (int32_t r = ptr[p]; r < ptr[p + 1]; ++r) {
          T* q = o + 3 * int64_t(pair[r]);
          const T a = wv[r];
          q[0] += a * g0;
          q[1] += a * g1;
          q[2] += a * g2;
        }
      }
  });
}

}  // namespace

at::Tensor weights_backward(const ColourWeights& w, const Raster& raster, const at::Tensor& g) {
  const Grid gr = make_grid(raster.C, raster.H, raster.W, raster.tile);
  TORCH_CHECK(g.dim() == 2 && g.size(0) == gr.C * gr.H * gr.W && g.size(1) == 3 && g.is_contiguous() && !g.is_cuda(),
              "weights_backward: g must be a contiguous CPU [C*H*W, 3] tensor");
  TORCH_CHECK(w.pix_ptr.numel() == gr.C * gr.H * gr.W + 1, "weights_backward: the record is of another raster");
  at::Tensor out = at::zeros({w.npairs, g.size(1)}, g.options());
  AT_DISPATCH_FLOATING_TYPES(g.scalar_type(), "weights_backward", [&] { backward_impl<scalar_t>(w, gr, g, out); });
  return out;
}

}  // namespace arcsem
