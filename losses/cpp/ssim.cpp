// Fused SSIM map of two image batches, and its gradient with respect to the first (the D-SSIM loss).
//
// Same sums as arcsem/imageops.py ssim_map (Wang et al. 2004; zero padding as 3DGS/2DGS): a separable Gaussian
// blur of x, y, x^2, y^2 and xy (along W, then along H), then per pixel
//   S = (2 mx my + C1)(2 cxy + C2) / ((mx^2 + my^2 + C1)(vx + vy + C2)),
//   vx = E[x^2] - mx^2, vy = E[y^2] - my^2, cxy = E[xy] - mx my  (E: the blur).
// Backward: with G = dL/dS per pixel and the partials of S in mx, E[x^2], E[xy] (a, b, c below),
//   dL/dx = blur(G a) + 2 x blur(G b) + y blur(G c)
// (the zero-padded blur with a symmetric kernel is its own transpose). Products are formed in padded row buffers,
// so the blur loops have no branches and vectorise over the W * ch values of a row.
//
// Images: [B, H, W, ch] channels last, contiguous, float or double; g: [K] (odd K) normalised 1-D Gaussian.
#include <ATen/Parallel.h>
#include <torch/extension.h>

#include <vector>

namespace {

constexpr double kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;
constexpr int64_t kRows = 4;  // rows per parallel task

struct Shape {
  int64_t B, H, W, ch, K;
  int64_t L() const { return W * ch; }           // values in a row
  int64_t rows() const { return B * H; }
  int64_t n() const { return rows() * L(); }     // values in a plane
  int64_t P() const { return (W + K - 1) * ch; } // values in a padded row
};

// h[q][j] = sum_k g[k] pad[q][j + k ch] for Q padded rows (length s.P()) -> Q rows of s.L()
template <typename T, int Q>
void blur_row(const Shape& s, const T* g, const T* pad, T* const* h, int64_t row) {
  const int64_t L = s.L(), P = s.P();
  for (int q = 0; q < Q; ++q) {
    T* out = h[q] + row * L;
    const T* in = pad + q * P;
    for (int64_t j = 0; j < L; ++j) out[j] = 0;
    for (int64_t k = 0; k < s.K; ++k) {
      const T gk = g[k];
      const T* ink = in + k * s.ch;
#pragma omp simd
      for (int64_t j = 0; j < L; ++j) out[j] += gk * ink[j];
    }
  }
}

// v[q][j] = sum_k g[k] h[q][r + k - K/2][j] over the rows of one image (zero outside), for row `row` = b H + r
template <typename T, int Q>
void blur_col(const Shape& s, const T* g, T* const* h, int64_t row, T* v /* [Q][L] */) {
  const int64_t L = s.L(), p = s.K / 2, r = row % s.H, first = row - r;
  const int64_t k0 = std::max<int64_t>(0, p - r), k1 = std::min<int64_t>(s.K, s.H + p - r);
  for (int q = 0; q < Q; ++q) {
    T* out = v + q * L;
    for (int64_t j = 0; j < L; ++j) out[j] = 0;
    for (int64_t k = k0; k < k1; ++k) {
      const T gk = g[k];
      const T* in = h[q] + (first + r + k - p) * L;
#pragma omp simd
      for (int64_t j = 0; j < L; ++j) out[j] += gk * in[j];
    }
  }
}

// copies Q rows into zero-padded buffers (K/2 pixels each side), f(q, value index) giving the value
template <typename T, int Q, typename F>
void pad_rows(const Shape& s, std::vector<T>& pad, const F& f) {
  const int64_t P = s.P(), off = (s.K / 2) * s.ch, L = s.L();
  pad.assign(Q * P, T(0));
  for (int q = 0; q < Q; ++q)
    for (int64_t j = 0; j < L; ++j) pad[q * P + off + j] = f(q, j);
}

// S = (a1 a2) / (b1 b2) from the blurs mx, my, E[x^2], E[y^2], E[xy] of a pixel
template <typename T>
inline void ssim_terms(T mx, T my, T sxx, T syy, T sxy, T& a1, T& a2, T& b1, T& b2) {
  a1 = 2 * mx * my + T(kC1);
  a2 = 2 * (sxy - mx * my) + T(kC2);
  b1 = mx * mx + my * my + T(kC1);
  b2 = (sxx - mx * mx) + (syy - my * my) + T(kC2);
}

Shape check(const at::Tensor& x, const at::Tensor& y, const at::Tensor& g) {
  TORCH_CHECK(x.dim() == 4 && x.sizes() == y.sizes(), "ssim: x, y must be [B, H, W, ch] of one shape");
  TORCH_CHECK(x.is_contiguous() && y.is_contiguous() && g.is_contiguous(), "ssim: inputs must be contiguous");
  TORCH_CHECK(x.device().is_cpu() && x.scalar_type() == y.scalar_type() && g.scalar_type() == x.scalar_type(),
              "ssim: CPU tensors of one floating type");
  TORCH_CHECK(g.dim() == 1 && g.numel() % 2 == 1, "ssim: the window must be 1-D with an odd size");
  return Shape{x.size(0), x.size(1), x.size(2), x.size(3), g.numel()};
}

}  // namespace

// -> {ssim map [B, H, W, ch], stats [5, B, H, W, ch]: the blurs of x, y, x^2, y^2, xy}
std::vector<at::Tensor> ssim_forward(const at::Tensor& x, const at::Tensor& y, const at::Tensor& g) {
  const Shape s = check(x, y, g);
  auto map = at::empty_like(x);
  auto stats = at::empty({5, s.B, s.H, s.W, s.ch}, x.options());
  auto hbuf = at::empty({5, s.B, s.H, s.W, s.ch}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "ssim_forward", [&] {
    using T = scalar_t;
    const T *xp = x.data_ptr<T>(), *yp = y.data_ptr<T>(), *gp = g.data_ptr<T>();
    T* h[5];
    for (int q = 0; q < 5; ++q) h[q] = hbuf.data_ptr<T>() + q * s.n();
    at::parallel_for(0, s.rows(), kRows, [&](int64_t b, int64_t e) {
      std::vector<T> pad;
      for (int64_t row = b; row < e; ++row) {
        const T *xr = xp + row * s.L(), *yr = yp + row * s.L();
        pad_rows<T, 5>(s, pad, [&](int q, int64_t j) {
          return q == 0 ? xr[j] : q == 1 ? yr[j] : q == 2 ? xr[j] * xr[j] : q == 3 ? yr[j] * yr[j] : xr[j] * yr[j];
        });
        blur_row<T, 5>(s, gp, pad.data(), h, row);
      }
    });
    T* st = stats.data_ptr<T>();
    T* mp = map.data_ptr<T>();
    at::parallel_for(0, s.rows(), kRows, [&](int64_t b, int64_t e) {
      std::vector<T> v(5 * s.L());
      for (int64_t row = b; row < e; ++row) {
        blur_col<T, 5>(s, gp, h, row, v.data());
        const int64_t L = s.L(), at = row * L;
        const T *mx = v.data(), *my = mx + L, *sxx = my + L, *syy = sxx + L, *sxy = syy + L;
_Pragma("omp simd")
        for (int64_t j = 0; j < L; ++j) {
          T a1, a2, b1, b2;
          ssim_terms(mx[j], my[j], sxx[j], syy[j], sxy[j], a1, a2, b1, b2);
          mp[at + j] = (a1 * a2) / (b1 * b2);
        }
        for (int q = 0; q < 5; ++q) std::copy(v.data() + q * L, v.data() + (q + 1) * L, st + q * s.n() + at);
      }
    });
  });
  return {map, stats};
}

// gradient of sum(g_map * ssim_map(x, y)) with respect to x -> [B, H, W, ch]
at::Tensor ssim_backward(const at::Tensor& g_map, const at::Tensor& x, const at::Tensor& y, const at::Tensor& g,
                         const at::Tensor& stats) {
  const Shape s = check(x, y, g);
  TORCH_CHECK(g_map.sizes() == x.sizes() && g_map.is_contiguous() && g_map.scalar_type() == x.scalar_type(),
              "ssim_backward: the map's gradient must be contiguous, shaped and typed as x");
  TORCH_CHECK(stats.is_contiguous() && stats.numel() == 5 * x.numel(), "ssim_backward: stats of ssim_forward");
  auto gx = at::empty_like(x);
  auto hbuf = at::empty({3, s.B, s.H, s.W, s.ch}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "ssim_backward", [&] {
    using T = scalar_t;
    const T *xp = x.data_ptr<T>(), *yp = y.data_ptr<T>(), *gp = g.data_ptr<T>(), *G = g_map.data_ptr<T>();
    const T* st = stats.data_ptr<T>();
    T* h[3];
    for (int q = 0; q < 3; ++q) h[q] = hbuf.data_ptr<T>() + q * s.n();
    at::parallel_for(0, s.rows(), kRows, [&](int64_t b, int64_t e) {
      std::vector<T> pad, d(3 * s.L());
      for (int64_t row = b; row < e; ++row) {
        const int64_t L = s.L(), at = row * L;
        const T *mx = st + at, *my = mx + s.n(), *sxx = my + s.n(), *syy = sxx + s.n(), *sxy = syy + s.n();
        // the partials of S in mx, E[x^2] and E[xy], times G
_Pragma("omp simd")
        for (int64_t j = 0; j < L; ++j) {
          T a1, a2, b1, b2;
          ssim_terms(mx[j], my[j], sxx[j], syy[j], sxy[j], a1, a2, b1, b2);
          const T S = (a1 * a2) / (b1 * b2), Gj = G[at + j];
          d[j] = Gj * (2 * my[j] * (a2 - a1) / (b1 * b2) - 2 * mx[j] * S * (1 / b1 - 1 / b2));
          d[L + j] = Gj * (-S / b2);
          d[2 * L + j] = Gj * (2 * a1 / (b1 * b2));
        }
        pad_rows<T, 3>(s, pad, [&](int q, int64_t j) { return d[q * L + j]; });
        blur_row<T, 3>(s, gp, pad.data(), h, row);
      }
    });
    T* out = gx.data_ptr<T>();
    at::parallel_for(0, s.rows(), kRows, [&](int64_t b, int64_t e) {
      std::vector<T> v(3 * s.L());
      for (int64_t row = b; row < e; ++row) {
        blur_col<T, 3>(s, gp, h, row, v.data());
        const int64_t L = s.L(), at = row * L;
_Pragma("omp simd")
        for (int64_t j = 0; j < L; ++j) out[at + j] = v[j] + 2 * xp[at + j] * v[L + j] + yp[at + j] * v[2 * L + j];
      }
    });
  });
  return gx;
}
