// Fused 2DGS normal-consistency loss (the official form), forward and backward; losses/geometry.py is the reference.
//
// World points P = o + D d from the depth map D and the camera's rays (origins o, directions d of unit camera z:
// Cameras.rays), given per camera as affine functions of the pixel centre (u, v): o = u o_u + v o_v + o_1, the same
// for d (pinhole and orthographic rays are affine in (u, v)). At an interior pixel the surface normal is
// n = c / max(|c|, 1e-12), c = (P[y+1] - P[y-1]) x (P[x+1] - P[x-1]) (central differences, as losses/geometry.py
// depth_normals); the loss is the mean over pixels
// with n != 0 of 1 - (N . n) alpha, N the rendered normal, alpha detached. Backward: dL/dN = -k alpha n,
// dL/dn = -k alpha N (k = g / count), through the normalisation to c, the cross product to the two differences,
// and the differences to P and D (a gather over each pixel's four neighbours).
//
// depth, alpha: [C, H, W]; normal: [C, H, W, 3]; o, d: [C, 3, 3] rows (o_u, o_v, o_1); contiguous CPU tensors of one
// floating type.
#include <ATen/Parallel.h>
#include <torch/extension.h>

#include <vector>

namespace {

constexpr double kEps = 1e-12;  // F.normalize's eps

struct Dims {
  int64_t C, H, W;
  int64_t rows() const { return C * H; }
};

template <typename T>
inline void sub3(const T* a, const T* b, T* r) { for (int k = 0; k < 3; ++k) r[k] = a[k] - b[k]; }
template <typename T>
inline void cross3(const T* a, const T* b, T* r) {
  r[0] = a[1] * b[2] - a[2] * b[1];
  r[1] = a[2] * b[0] - a[0] * b[2];
  r[2] = a[0] * b[1] - a[1] * b[0];
}

template <typename T>
struct In {
  const T *D, *o, *d, *N, *A;
  Dims s;
  // ray direction (and origin) at the pixels of one row: dir, org [W][3]
  void rays(int64_t row, T* dir, T* org) const {
    const int64_t c = row / s.H;
    const T v = T(row % s.H) + T(0.5), *dc = d + 9 * c, *oc = o + 9 * c;
    for (int64_t x = 0; x < s.W; ++x) {
      const T u = T(x) + T(0.5);
      for (int k = 0; k < 3; ++k) {
        dir[3 * x + k] = u * dc[k] + v * dc[3 + k] + dc[6 + k];
        org[3 * x + k] = u * oc[k] + v * oc[3 + k] + oc[6 + k];
      }
    }
  }
  // world points of every pixel -> P [C, H, W, 3]
  void points(T* P) const {
    at::parallel_for(0, s.rows(), 8, [&](int64_t b, int64_t e) {
      std::vector<T> dir(3 * s.W), org(3 * s.W);
      for (int64_t row = b; row < e; ++row) {
        rays(row, dir.data(), org.data());
        T* Pr = P + 3 * row * s.W;
        const T* Dr = D + row * s.W;
        for (int64_t x = 0; x < s.W; ++x)
          for (int k = 0; k < 3; ++k) Pr[3 * x + k] = org[3 * x + k] + Dr[x] * dir[3 * x + k];
      }
    });
  }
  bool interior_row(int64_t row) const {
    const int64_t y = row % s.H;
    return y > 0 && y < s.H - 1;
  }
};

// central differences at interior pixel p of the point map P: dy, dx and c = dy x dx
template <typename T>
inline void diffs(const T* P, int64_t p, int64_t W, T* dy, T* dx, T* c) {
  sub3(P + 3 * (p + W), P + 3 * (p - W), dy);
  sub3(P + 3 * (p + 1), P + 3 * (p - 1), dx);
  cross3(dy, dx, c);
}

// f(row, p, dy, dx, c, |c|, 1 / max(|c|, eps)) at every interior pixel p whose surface normal is not zero
template <typename T, class F>
void each_normal(const In<T>& in, const T* P, const F& f) {
  const Dims& s = in.s;
  at::parallel_for(0, s.rows(), 8, [&](int64_t b, int64_t e) {
    for (int64_t row = b; row < e; ++row)
      for (int64_t x = 1; x < s.W - 1 && in.interior_row(row); ++x) {
        const int64_t p = row * s.W + x;
        T dy[3], dx[3], c[3];
        diffs(P, p, s.W, dy, dx, c);
        const T len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        if (len > T(0)) f(row, p, dy, dx, c, len, T(1) / std::max(len, T(kEps)));  // n = 0 (or NaN): not counted
      }
  });
}

Dims check(const at::Tensor& depth, const at::Tensor& o, const at::Tensor& d, const at::Tensor& normal,
           const at::Tensor& alpha) {
  TORCH_CHECK(depth.dim() == 3, "normal_consistency: depth must be [C, H, W]");
  const Dims s{depth.size(0), depth.size(1), depth.size(2)};
  TORCH_CHECK(normal.dim() == 4 && normal.size(0) == s.C && normal.size(1) == s.H && normal.size(2) == s.W &&
              normal.size(3) == 3, "normal_consistency: normals must be [C, H, W, 3]");
  for (const auto* t : {&o, &d})
    TORCH_CHECK(t->dim() == 3 && t->size(0) == s.C && t->size(1) == 3 && t->size(2) == 3,
                "normal_consistency: rays must be [C, 3, 3] affine coefficients");
  TORCH_CHECK(alpha.sizes() == depth.sizes(), "normal_consistency: alpha must be [C, H, W]");
  for (const auto* t : {&depth, &o, &d, &normal, &alpha})
    TORCH_CHECK(t->is_contiguous() && t->device().is_cpu() && t->scalar_type() == depth.scalar_type(),
                "normal_consistency: contiguous CPU tensors of one floating type");
  return s;
}

}  // namespace

// -> {loss (0-dim), pixels counted (0-dim, double)}
std::vector<at::Tensor> normal_consistency_forward(const at::Tensor& depth, const at::Tensor& o, const at::Tensor& d,
                                                   const at::Tensor& normal, const at::Tensor& alpha) {
  const Dims s = check(depth, o, d, normal, alpha);
  std::vector<double> err(s.rows(), 0.0), cnt(s.rows(), 0.0);  // per row: a fixed summation order
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "normal_consistency_forward", [&] {
    using T = scalar_t;
    const In<T> in{depth.data_ptr<T>(), o.data_ptr<T>(), d.data_ptr<T>(), normal.data_ptr<T>(), alpha.data_ptr<T>(), s};
    std::vector<T> P(3 * s.rows() * s.W);
    in.points(P.data());
    each_normal(in, P.data(), [&](int64_t row, int64_t p, const T*, const T*, const T* c, T, T inv) {
      const T dot = (in.N[3 * p] * c[0] + in.N[3 * p + 1] * c[1] + in.N[3 * p + 2] * c[2]) * inv;
      err[row] += double(T(1) - dot * in.A[p]);
      cnt[row] += 1.0;
    });
  });
  double e = 0, n = 0;
  for (int64_t r = 0; r < s.rows(); ++r) e += err[r], n += cnt[r];
  auto opts = depth.options();
  return {at::scalar_tensor(e / std::max(n, 1.0), opts), at::scalar_tensor(n, opts.dtype(at::kDouble))};
}

// gradient g of the loss -> {g_depth [C, H, W], g_normal [C, H, W, 3]}
std::vector<at::Tensor> normal_consistency_backward(double g, double count, const at::Tensor& depth,
                                                    const at::Tensor& o,
                                                    const at::Tensor& d, const at::Tensor& normal,
                                                    const at::Tensor& alpha) {
  const Dims s = check(depth, o, d, normal, alpha);
  auto g_depth = at::empty_like(depth);
  auto g_normal = at::zeros_like(normal);
  auto gdiff = at::zeros({s.C, s.H, s.W, 6}, depth.options());  // per pixel: dL/d(dy), dL/d(dx)
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "normal_consistency_backward", [&] {
    using T = scalar_t;
    const In<T> in{depth.data_ptr<T>(), o.data_ptr<T>(), d.data_ptr<T>(), normal.data_ptr<T>(), alpha.data_ptr<T>(), s};
    const T k = T(g / std::max(count, 1.0));
    T *gN = g_normal.data_ptr<T>(), *gd = gdiff.data_ptr<T>();
    std::vector<T> P(3 * s.rows() * s.W);
    in.points(P.data());
    each_normal(in, P.data(), [&](int64_t, int64_t p, const T* dy, const T* dx, const T* c, T len, T inv) {
      const T w = -k * in.A[p];
      T n[3], gn[3], gc[3];
      for (int q = 0; q < 3; ++q) {
        n[q] = c[q] * inv;
        gN[3 * p + q] = w * n[q];
        gn[q] = w * in.N[3 * p + q];
      }
      // n = c / max(|c|, eps): (I - n n^T) / |c| above eps, I / eps below
      const T proj = len > T(kEps) ? n[0] * gn[0] + n[1] * gn[1] + n[2] * gn[2] : T(0);
      for (int q = 0; q < 3; ++q) gc[q] = (gn[q] - n[q] * proj) * inv;
      cross3(dx, gc, gd + 6 * p);      // c = dy x dx: dL/d(dy) = dx x gc
      cross3(gc, dy, gd + 6 * p + 3);  //              dL/d(dx) = gc x dy
    });
    T* gD = g_depth.data_ptr<T>();
    at::parallel_for(0, s.rows(), 8, [&](int64_t b, int64_t e) {
      std::vector<T> dir(3 * s.W), org(3 * s.W);
      for (int64_t row = b; row < e; ++row) {
        const int64_t y = row % s.H;
        in.rays(row, dir.data(), org.data());
        for (int64_t x = 0; x < s.W; ++x) {
          const int64_t p = row * s.W + x;
          T gP[3] = {0, 0, 0};  // P[p] is P[y+1] of the pixel above, P[y-1] of the one below, ...
          for (int q = 0; q < 3; ++q) {
            if (y > 0) gP[q] += gd[6 * (p - s.W) + q];
            if (y < s.H - 1) gP[q] -= gd[6 * (p + s.W) + q];
            if (x > 0) gP[q] += gd[6 * (p - 1) + 3 + q];
            if (x < s.W - 1) gP[q] -= gd[6 * (p + 1) + 3 + q];
          }
          gD[p] = gP[0] * dir[3 * x] + gP[1] * dir[3 * x + 1] + gP[2] * dir[3 * x + 2];
        }
      }
    });
  });
  return {g_depth, g_normal};
}
