// Fused CPU ray marching of a sparse SH voxel grid (forward + backward), one ray per loop iteration.
// Same sampling, interpolation and compositing as render.py (the PyTorch reference):
// segments of length `step` (world) partition [t_near, t_far]; samples at their midpoints; trilinear
// interpolation on the vertex grid with empty corners = 0; tau = relu(sigma) * delta * |d| / scale;
// colour = act(relu(SH . basis + 0.5)); samples with transmittance < stop_thresh end the ray.
// Outputs per ray: rgb (no background), alpha = sum w, wt = sum w t. The backward marches again and
// uses Q = g . outputs for the suffix sums, so nothing per sample is stored.
#include <omp.h>
#include <torch/extension.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace {

template <typename T>
void sh_basis(int degree, T x, T y, T z, T* b) {
  const T C0 = 0.28209479177387814, C1 = 0.4886025119029199;
  b[0] = C0;
  if (degree >= 1) { b[1] = -C1 * y; b[2] = C1 * z; b[3] = -C1 * x; }
  if (degree >= 2) {
    b[4] = T(1.0925484305920792) * x * y;
    b[5] = T(-1.0925484305920792) * y * z;
    b[6] = T(0.31539156525252005) * (2 * z * z - x * x - y * y);
    b[7] = T(-1.0925484305920792) * x * z;
    b[8] = T(0.5462742152960396) * (x * x - y * y);
  }
  if (degree >= 3) {
    T xx = x * x, yy = y * y, zz = z * z;
    b[9] = T(-0.5900435899266435) * y * (3 * xx - yy);
    b[10] = T(2.890611442640554) * x * y * z;
    b[11] = T(-0.4570457994644658) * y * (4 * zz - xx - yy);
    b[12] = T(0.3731763325901154) * z * (2 * zz - 3 * xx - 3 * yy);
    b[13] = T(-0.4570457994644658) * x * (4 * zz - xx - yy);
    b[14] = T(1.445305721320277) * z * (xx - yy);
    b[15] = T(-0.5900435899266435) * x * (xx - 3 * yy);
  }
}

struct Grid {
  const int32_t* index;
  const uint8_t* cell_occ;
  int64_t X, Y, Z;
  double lo[3], vs[3];
};

// The ray's sample range; returns the number of segments.
template <typename T>
int64_t ray_setup(const T* o, const T* d, const double* lo, const double* hi, double step, T& tn, T& tf, T& dt) {
  T t_near = 0, t_far = std::numeric_limits<T>::infinity();
  T t0s[3], t1s[3];
  for (int a = 0; a < 3; ++a) {
    T da = std::abs(d[a]) < T(1e-12) ? T(1e-12) : d[a];
    T inv = T(1) / da;
    t0s[a] = (T(lo[a]) - o[a]) * inv;
    t1s[a] = (T(hi[a]) - o[a]) * inv;
  }
  T mx = std::max(std::min(t0s[0], t1s[0]), std::max(std::min(t0s[1], t1s[1]), std::min(t0s[2], t1s[2])));
  T mn = std::min(std::max(t0s[0], t1s[0]), std::min(std::max(t0s[1], t1s[1]), std::max(t0s[2], t1s[2])));
  t_near = std::max(mx, T(0));
  t_far = mn;
  T dn = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  dt = T(step) / dn;
  tn = t_near;
  tf = t_far;
  T n = std::ceil(std::max((t_far - t_near) / dt, T(0)) - T(1e-6));
  return n > 0 ? (int64_t)n : 0;
}

// Corner rows and trilinear weights of grid coordinate g; false when the cell has no occupied corner.
template <typename T>
bool corners(const Grid& G, const T* g, int64_t* rows, T* w) {
  int64_t b[3];
  T f[3];
  const int64_t R[3] = {G.X, G.Y, G.Z};
  for (int a = 0; a < 3; ++a) {
    T ga = std::min(std::max(g[a], T(0)), T(R[a] - 1));
    int64_t fl = (int64_t)std::floor(ga);
    b[a] = std::min(fl, R[a] - 2);
    f[a] = ga - T(b[a]);
  }
  int64_t lin = (b[0] * G.Y + b[1]) * G.Z + b[2];
  if (!G.cell_occ[lin]) return false;
  int c = 0;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int k = 0; k < 2; ++k, ++c) {
        int32_t r = G.index[lin + (i * G.Y + j) * G.Z + k];
        T wc = (i ? f[0] : 1 - f[0]) * (j ? f[1] : 1 - f[1]) * (k ? f[2] : 1 - f[2]);
        rows[c] = r < 0 ? 0 : r;
        w[c] = r < 0 ? T(0) : wc;
      }
  return true;
}

struct Params {
  double lo[3], hi[3], step, scale, stop;
  int degree, K, Kstore;
  bool has_act;
};

template <typename T>
void forward_impl(const Params& P, const Grid& G, const T* ro, const T* rd, const T* dens, const T* sh,
                  const T* actW, const T* actB, int64_t nrays, T* rgb, T* alpha, T* wt) {
#pragma omp parallel for schedule(dynamic, 64)
  for (int64_t r = 0; r < nrays; ++r) {
    const T* o = ro + 3 * r;
    const T* d = rd + 3 * r;
    T tn, tf, dt;
    int64_t n = ray_setup<T>(o, d, P.lo, P.hi, P.step, tn, tf, dt);
    T dn = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    T basis[16];
    sh_basis<T>(P.degree, d[0] / dn, d[1] / dn, d[2] / dn, basis);
    T Tr = 1, acc[3] = {0, 0, 0}, a_sum = 0, wt_sum = 0;
    int64_t rows[8];
    T w[8], g[3];
    for (int64_t s = 0; s < n; ++s) {
      T t0 = tn + T(s) * dt;
      T delta = std::min(std::max(tf - t0, T(0)), dt);
      T tm = t0 + T(0.5) * delta;
      for (int a = 0; a < 3; ++a) g[a] = (o[a] + tm * d[a] - T(G.lo[a])) / T(G.vs[a]);
      if (!corners<T>(G, g, rows, w)) continue;
      T raw = 0;
      for (int c = 0; c < 8; ++c) raw += w[c] * dens[rows[c]];
      if (raw <= 0) continue;
      if (Tr < T(P.stop)) break;
      T tau = raw * delta * dn / T(P.scale);
      T ws = Tr * (1 - std::exp(-tau));
      T col[3] = {T(0.5), T(0.5), T(0.5)};
      for (int c = 0; c < 8; ++c) {
        if (w[c] == 0) continue;
        const T* q = sh + rows[c] * P.Kstore * 3;
        for (int k = 0; k < P.K; ++k) {
          T bw = basis[k] * w[c];
          for (int ch = 0; ch < 3; ++ch) col[ch] += bw * q[k * 3 + ch];
        }
      }
      for (int ch = 0; ch < 3; ++ch) {
        T v = std::max(col[ch], T(0));
        if (P.has_act) v = std::min(std::max(actW[3 * r + ch] * v + actB[3 * r + ch], T(0)), T(1));
        acc[ch] += ws * v;
      }
      a_sum += ws;
      wt_sum += ws * tm;
      Tr *= std::exp(-tau);
    }
    for (int ch = 0; ch < 3; ++ch) rgb[3 * r + ch] = acc[ch];
    alpha[r] = a_sum;
    wt[r] = wt_sum;
  }
}

// Gradient sink: with private buffers (one per thread) plain adds, else atomic adds into one buffer.
template <typename T>
inline void grad_add(T* p, T v, bool atomic) {
  if (atomic) {
#pragma omp atomic
    *p += v;
  } else {
    *p += v;
  }
}

template <typename T>
void backward_impl(const Params& P, const Grid& G, const T* ro, const T* rd, const T* dens, const T* sh,
                   const T* actW, const T* actB, int64_t nrays, const T* rgb, const T* alpha, const T* wt,
                   const T* g_rgb, const T* g_alpha, const T* g_wt, T* const* gd_t, T* const* gsh_t, bool atomic,
                   T* gW, T* gB) {
  // static schedule: a fixed ray -> thread map, so private-buffer gradients are bitwise reproducible
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < nrays; ++r) {
    const int tid = atomic ? 0 : omp_get_thread_num();
    T* gd = gd_t[tid];
    T* gsh = gsh_t[tid];
    const T* o = ro + 3 * r;
    const T* d = rd + 3 * r;
    const T* gr = g_rgb + 3 * r;
    T Q = gr[0] * rgb[3 * r] + gr[1] * rgb[3 * r + 1] + gr[2] * rgb[3 * r + 2] + g_alpha[r] * alpha[r] +
          g_wt[r] * wt[r];
    T tn, tf, dt;
    int64_t n = ray_setup<T>(o, d, P.lo, P.hi, P.step, tn, tf, dt);
    T dn = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    T basis[16];
    sh_basis<T>(P.degree, d[0] / dn, d[1] / dn, d[2] / dn, basis);
    T Tr = 1, prefix = 0;
    int64_t rows[8];
    T w[8], g[3];
    for (int64_t s = 0; s < n; ++s) {
      T t0 = tn + T(s) * dt;
      T delta = std::min(std::max(tf - t0, T(0)), dt);
      T tm = t0 + T(0.5) * delta;
      for (int a = 0; a < 3; ++a) g[a] = (o[a] + tm * d[a] - T(G.lo[a])) / T(G.vs[a]);
      if (!corners<T>(G, g, rows, w)) continue;
      T raw = 0;
      for (int c = 0; c < 8; ++c) raw += w[c] * dens[rows[c]];
      if (raw <= 0) continue;
      if (Tr < T(P.stop)) break;
      T k_tau = delta * dn / T(P.scale);
      T tau = raw * k_tau;
      T e = std::exp(-tau);
      T ws = Tr * (1 - e);
      T pre[3] = {T(0.5), T(0.5), T(0.5)};
      for (int c = 0; c < 8; ++c) {
        if (w[c] == 0) continue;
        const T* q = sh + rows[c] * P.Kstore * 3;
        for (int k = 0; k < P.K; ++k)
          for (int ch = 0; ch < 3; ++ch) pre[ch] += basis[k] * w[c] * q[k * 3 + ch];
      }
      T qs = g_alpha[r] + g_wt[r] * tm, dpre[3];
      for (int ch = 0; ch < 3; ++ch) {
        T v = std::max(pre[ch], T(0));
        T dv = ws * gr[ch];  // dL / d colour
        if (P.has_act) {
          T u = actW[3 * r + ch] * v + actB[3 * r + ch];
          bool inside = u > 0 && u < 1;
          T va = std::min(std::max(u, T(0)), T(1));
          qs += gr[ch] * va;
          if (inside) {
            gW[3 * r + ch] += dv * v;
            gB[3 * r + ch] += dv;
            dv *= actW[3 * r + ch];
          } else {
            dv = 0;
          }
        } else {
          qs += gr[ch] * v;
        }
        dpre[ch] = pre[ch] > 0 ? dv : T(0);
      }
      prefix += ws * qs;
      T dtau = Tr * e * qs - (Q - prefix);
      T draw = dtau * k_tau;
      for (int c = 0; c < 8; ++c) {
        if (w[c] == 0) continue;
        grad_add(gd + rows[c], w[c] * draw, atomic);
        T* gq = gsh + rows[c] * P.Kstore * 3;
        for (int k = 0; k < P.K; ++k)
          for (int ch = 0; ch < 3; ++ch)
            if (dpre[ch] != 0) grad_add(gq + k * 3 + ch, w[c] * basis[k] * dpre[ch], atomic);
      }
      Tr *= e;
    }
  }
}

Params make_params(const torch::Tensor& bounds, double step, double scale, double stop, int degree, int64_t Kstore,
                   bool has_act) {
  Params P;
  auto b = bounds.to(torch::kFloat64).contiguous();
  const double* bp = b.data_ptr<double>();
  for (int a = 0; a < 3; ++a) { P.lo[a] = bp[a]; P.hi[a] = bp[3 + a]; }
  P.step = step; P.scale = scale; P.stop = stop; P.degree = degree;
  P.K = (degree + 1) * (degree + 1); P.Kstore = Kstore; P.has_act = has_act;
  return P;
}

Grid make_grid(const torch::Tensor& index, const torch::Tensor& cell_occ, const Params& P) {
  Grid G;
  G.index = index.data_ptr<int32_t>();
  G.cell_occ = cell_occ.data_ptr<uint8_t>();
  G.X = index.size(0); G.Y = index.size(1); G.Z = index.size(2);
  const int64_t R[3] = {G.X, G.Y, G.Z};
  for (int a = 0; a < 3; ++a) { G.lo[a] = P.lo[a]; G.vs[a] = (P.hi[a] - P.lo[a]) / double(std::max<int64_t>(R[a] - 1, 1)); }
  return G;
}

}  // namespace

std::vector<torch::Tensor> plx_forward(torch::Tensor ro, torch::Tensor rd, torch::Tensor index, torch::Tensor cell_occ,
                                       torch::Tensor dens, torch::Tensor sh, torch::Tensor actW, torch::Tensor actB,
                                       torch::Tensor bounds, double step, double scale, double stop, int64_t degree,
                                       bool has_act) {
  Params P = make_params(bounds, step, scale, stop, (int)degree, sh.size(1), has_act);
  Grid G = make_grid(index, cell_occ, P);
  int64_t R = ro.size(0);
  auto rgb = torch::zeros({R, 3}, ro.options());
  auto alpha = torch::zeros({R}, ro.options());
  auto wt = torch::zeros({R}, ro.options());
  AT_DISPATCH_FLOATING_TYPES(ro.scalar_type(), "plx_forward", [&] {
    forward_impl<scalar_t>(P, G, ro.data_ptr<scalar_t>(), rd.data_ptr<scalar_t>(), dens.data_ptr<scalar_t>(),
                           sh.data_ptr<scalar_t>(), has_act ? actW.data_ptr<scalar_t>() : nullptr,
                           has_act ? actB.data_ptr<scalar_t>() : nullptr, R, rgb.data_ptr<scalar_t>(),
                           alpha.data_ptr<scalar_t>(), wt.data_ptr<scalar_t>());
  });
  return {rgb, alpha, wt};
}

std::vector<torch::Tensor> plx_backward(torch::Tensor ro, torch::Tensor rd, torch::Tensor index,
                                        torch::Tensor cell_occ, torch::Tensor dens, torch::Tensor sh,
                                        torch::Tensor actW, torch::Tensor actB, torch::Tensor bounds, double step,
                                        double scale, double stop, int64_t degree, bool has_act, torch::Tensor rgb,
                                        torch::Tensor alpha, torch::Tensor wt, torch::Tensor g_rgb,
                                        torch::Tensor g_alpha, torch::Tensor g_wt, double private_bytes) {
  Params P = make_params(bounds, step, scale, stop, (int)degree, sh.size(1), has_act);
  Grid G = make_grid(index, cell_occ, P);
  int64_t R = ro.size(0);
  auto gd = torch::zeros_like(dens);
  auto gsh = torch::zeros_like(sh);
  auto gW = torch::zeros({R, 3}, ro.options());
  auto gB = torch::zeros({R, 3}, ro.options());
  // Private per-thread buffers avoid atomics; used while they cost at most `private_bytes` in total.
  int nt = std::max(1, omp_get_max_threads());
  bool atomic = nt > 1 && double(nt - 1) * double(sh.numel() + dens.numel()) * double(sh.element_size()) >
                              private_bytes;
  int nbuf = atomic ? 0 : nt - 1;
  auto extra_d = torch::zeros({nbuf, dens.numel()}, dens.options());
  auto extra_sh = torch::zeros({nbuf, sh.numel()}, sh.options());
  AT_DISPATCH_FLOATING_TYPES(ro.scalar_type(), "plx_backward", [&] {
    std::vector<scalar_t*> pd(nt), psh(nt);
    pd[0] = gd.data_ptr<scalar_t>();
    psh[0] = gsh.data_ptr<scalar_t>();
    for (int i = 0; i < nbuf; ++i) {
      pd[i + 1] = extra_d.data_ptr<scalar_t>() + i * dens.numel();
      psh[i + 1] = extra_sh.data_ptr<scalar_t>() + i * sh.numel();
    }
    backward_impl<scalar_t>(P, G, ro.data_ptr<scalar_t>(), rd.data_ptr<scalar_t>(), dens.data_ptr<scalar_t>(),
                            sh.data_ptr<scalar_t>(), has_act ? actW.data_ptr<scalar_t>() : nullptr,
                            has_act ? actB.data_ptr<scalar_t>() : nullptr, R, rgb.data_ptr<scalar_t>(),
                            alpha.data_ptr<scalar_t>(), wt.data_ptr<scalar_t>(), g_rgb.data_ptr<scalar_t>(),
                            g_alpha.data_ptr<scalar_t>(), g_wt.data_ptr<scalar_t>(), pd.data(), psh.data(), atomic,
                            gW.data_ptr<scalar_t>(), gB.data_ptr<scalar_t>());
  });
  if (nbuf > 0) {
    gd.add_(extra_d.sum(0).view_as(gd));
    gsh.add_(extra_sh.sum(0).view_as(gsh));
  }
  return {gd, gsh, gW, gB};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &plx_forward, "Plenoxels fused ray marching (forward)");
  m.def("backward", &plx_backward, "Plenoxels fused ray marching (backward)");
}
