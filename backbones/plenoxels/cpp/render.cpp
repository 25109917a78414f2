// Fused CPU ray marching of a sparse SH voxel grid (forward + backward), one ray per loop iteration.
// Same sampling, interpolation and compositing as render.py (the PyTorch reference), see march.h:
// trilinear interpolation on the vertex grid with empty corners = 0; tau = relu(sigma) * delta * |d| / scale;
// colour = act(relu(SH . basis + 0.5)); the ray ends once its transmittance falls below stop_thresh.
// Only samples in live cells are visited (empty-space skipping on the block distances of live()); a cell's
// corners are read and their SH evaluated once per cell, not per sample (cell.h); the SH degree is a
// template parameter, so those sums are fixed-length loops.
// Outputs per ray: rgb (no background), alpha = sum w, wt = sum w t, and the moments about the ray's entry
// mom = (sum w u, sum w u^2), u = t - t_near (the distortion, alpha mom1 - mom0^2, is formed in Python). The
// backward marches again and uses Q = g . outputs for the suffix sums, so nothing per sample is stored.
// The entry points and their argument structs are declared in api.h (bound in module.cpp).
#include <omp.h>
#include <torch/extension.h>

#include <vector>

#include "api.h"
#include "cell.h"
#include "live.h"
#include "march.h"

using plx::Cell;
using plx::CellGrad;
using plx::Grid;
using plx::Sink;
using plx::num_coef;
using plx::Ray;
using plx::Sample;

namespace {

struct Params {
  double hi[3], step, scale, stop;
  int64_t stride;  // floats per SH row (Kstore * 3)
  bool has_act;
};

// One sample of a ray in the cached cell: its weight ws = T (1 - e), e = exp(-tau), and colour v[3] (after ReLU
// and ACT); false when its density is not positive (it contributes nothing).
template <typename T>
struct Shade {
  T w[8], raw, e, ws, pre[3], v[3];
};

template <typename T, int DEG>
inline bool shade(const Params& P, const Cell<T, DEG>& cell, const Sample<T>& smp, T kscale, T Tr, const T* aw,
                  const T* ab, Shade<T>& o) {
  o.raw = cell.weights(smp.f, o.w);
  if (o.raw <= 0) return false;
  o.e = std::exp(-o.raw * (smp.delta * kscale));
  o.ws = Tr * (1 - o.e);
  cell.colour(o.w, o.pre);
  for (int ch = 0; ch < 3; ++ch) {
    o.v[ch] = std::max(o.pre[ch], T(0));
    if (P.has_act) o.v[ch] = std::min(std::max(aw[ch] * o.v[ch] + ab[ch], T(0)), T(1));
  }
  return true;
}

template <typename T, int DEG>
void forward_impl(const Params& P, const Grid& G, const T* ro, const T* rd, const T* dens, const T* sh,
                  const T* actW, const T* actB, int64_t nrays, T* rgb, T* alpha, T* wt, T* mom) {
#pragma omp parallel for schedule(dynamic, 64)
  for (int64_t r = 0; r < nrays; ++r) {
    Ray<T, DEG> ray;
    plx::setup_ray<T, DEG>(G, P.hi, P.step, ro + 3 * r, rd + 3 * r, ray);
    const T kscale = ray.dn / T(P.scale);
    const T* aw = P.has_act ? actW + 3 * r : nullptr;
    const T* ab = P.has_act ? actB + 3 * r : nullptr;
    T Tr = 1, acc[3] = {0, 0, 0}, a_sum = 0, wt_sum = 0, m0 = 0, m1 = 0;
    Cell<T, DEG> cell;
    Shade<T> o;
    plx::march<T, DEG>(G, ray, [&](const Sample<T>& smp) {
      if (smp.lin != cell.lin) cell.load(G, dens, sh, P.stride, ray.basis, smp.lin);
      if (!shade<T, DEG>(P, cell, smp, kscale, Tr, aw, ab, o)) return true;
      for (int ch = 0; ch < 3; ++ch) acc[ch] += o.ws * o.v[ch];
      a_sum += o.ws;
      wt_sum += o.ws * smp.tm;
      const T u = smp.tm - ray.tn;
      m0 += o.ws * u;
      m1 += o.ws * u * u;
      Tr *= o.e;
      return Tr >= T(P.stop);
    });
    for (int ch = 0; ch < 3; ++ch) rgb[3 * r + ch] = acc[ch];
    alpha[r] = a_sum;
    wt[r] = wt_sum;
    mom[2 * r] = m0;
    mom[2 * r + 1] = m1;
  }
}

template <typename T, int DEG>
void backward_impl(const Params& P, const Grid& G, const T* ro, const T* rd, const T* dens, const T* sh,
                   const T* actW, const T* actB, int64_t nrays, const T* rgb, const T* alpha, const T* wt,
                   const T* mom, const T* g_rgb, const T* g_alpha, const T* g_wt, const T* g_mom,
                   std::vector<Sink<T>>& sinks, T* gW, T* gB) {
  // static schedule: a fixed ray -> thread map, so the per-thread sums are bitwise reproducible
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < nrays; ++r) {
    Sink<T>& sink = sinks[omp_get_thread_num()];
    const T* gr = g_rgb + 3 * r;
    const T* gm = g_mom + 2 * r;
    const T Q = gr[0] * rgb[3 * r] + gr[1] * rgb[3 * r + 1] + gr[2] * rgb[3 * r + 2] + g_alpha[r] * alpha[r] +
                g_wt[r] * wt[r] + gm[0] * mom[2 * r] + gm[1] * mom[2 * r + 1];
    Ray<T, DEG> ray;
    plx::setup_ray<T, DEG>(G, P.hi, P.step, ro + 3 * r, rd + 3 * r, ray);
    const T kscale = ray.dn / T(P.scale);
    const T* aw = P.has_act ? actW + 3 * r : nullptr;
    const T* ab = P.has_act ? actB + 3 * r : nullptr;
    T Tr = 1, prefix = 0;
    Cell<T, DEG> cell;
    CellGrad<T, DEG> grad;
    Shade<T> o;
    plx::march<T, DEG>(G, ray, [&](const Sample<T>& smp) {
      if (smp.lin != cell.lin) {
        grad.flush(cell, ray.basis, sink);
        cell.load(G, dens, sh, P.stride, ray.basis, smp.lin);
      }
      if (!shade<T, DEG>(P, cell, smp, kscale, Tr, aw, ab, o)) return true;
      const T u = smp.tm - ray.tn;
      T qs = g_alpha[r] + g_wt[r] * smp.tm + (gm[0] + gm[1] * u) * u, dpre[3];
      for (int ch = 0; ch < 3; ++ch) {
        T dv = o.ws * gr[ch];  // dL / d colour
        qs += gr[ch] * o.v[ch];
        if (P.has_act) {
          T u = aw[ch] * std::max(o.pre[ch], T(0)) + ab[ch];
          if (u > 0 && u < 1) {
            gW[3 * r + ch] += dv * std::max(o.pre[ch], T(0));
            gB[3 * r + ch] += dv;
            dv *= aw[ch];
          } else {
            dv = 0;
          }
        }
        dpre[ch] = o.pre[ch] > 0 ? dv : T(0);
      }
      prefix += o.ws * qs;
      grad.add(o.w, (Tr * o.e * qs - (Q - prefix)) * (smp.delta * kscale), dpre);
      Tr *= o.e;
      return Tr >= T(P.stop);
    });
    grad.flush(cell, ray.basis, sink);
  }
}

// Largest rendering weight of each stored point over the rays (pruning): a composited sample counts for each
// corner with a positive trilinear weight, as upsample.py's max_weights. Per-thread buffers, max-reduced.
template <typename T, int DEG>
void max_weights_impl(const Params& P, const Grid& G, const T* ro, const T* rd, const T* dens, int64_t nrays,
                      T* best, int64_t M) {
  const int nt = std::max(1, omp_get_max_threads());
  std::vector<T> priv(size_t(nt - 1) * size_t(M), T(0));
#pragma omp parallel for schedule(dynamic, 64)
  for (int64_t r = 0; r < nrays; ++r) {
    const int tid = omp_get_thread_num();
    T* out = tid == 0 ? best : priv.data() + size_t(tid - 1) * size_t(M);
    Ray<T, DEG> ray;
    plx::setup_ray<T, DEG>(G, P.hi, P.step, ro + 3 * r, rd + 3 * r, ray);
    const T kscale = ray.dn / T(P.scale);
    T Tr = 1;
    Cell<T, 0> cell;
    T w[8];
    plx::march<T, DEG>(G, ray, [&](const Sample<T>& smp) {
      if (smp.lin != cell.lin) cell.load(G, dens, nullptr, 0, ray.basis, smp.lin);
      T raw = cell.weights(smp.f, w);
      if (raw <= 0) return true;
      T e = std::exp(-raw * (smp.delta * kscale));
      T ws = Tr * (1 - e);
      for (int c = 0; c < 8; ++c)
        if (w[c] > 0) out[cell.rows[c]] = std::max(out[cell.rows[c]], ws);
      Tr *= e;
      return Tr >= T(P.stop);
    });
  }
  for (int t = 1; t < nt; ++t)
    for (int64_t m = 0; m < M; ++m) best[m] = std::max(best[m], priv[size_t(t - 1) * size_t(M) + size_t(m)]);
}

// The rows any sink touched, sorted and unique: their bits in a bitmap of the M rows (M / 8 bytes), read back
// in order (a word at a time, skipping empty words).
template <typename T>
std::vector<int64_t> touched_rows(const std::vector<Sink<T>>& sinks, int64_t M) {
  std::vector<uint64_t> bits(size_t((M + 63) >> 6), 0);
  size_t n = 0;
  for (const auto& k : sinks) {
    n += k.rows.size();
    for (int64_t m : k.rows) bits[size_t(m >> 6)] |= uint64_t(1) << (m & 63);
  }
  std::vector<int64_t> rows;
  rows.reserve(n);
  for (size_t w = 0; w < bits.size(); ++w)
    for (uint64_t b = bits[w]; b != 0; b &= b - 1) rows.push_back(int64_t(w << 6) + __builtin_ctzll(b));
  return rows;
}

// Sums the sinks' slots of `rows` (in sink order: reproducible) into compact tables, then resets the slots.
template <typename T>
void collect(const std::vector<int64_t>& rows, std::vector<Sink<T>>& sinks, int64_t stride, T* out_d, T* out_sh) {
  const int64_t n = int64_t(rows.size());
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i) {
    const int64_t m = rows[i];
    T* od = out_d + i;
    T* osh = out_sh + i * stride;
    *od = 0;
    for (int64_t j = 0; j < stride; ++j) osh[j] = 0;
    for (const auto& k : sinks) {
      const int32_t s = k.slot[m];
      if (s < 0) continue;
      const T* q = k.get(s);
      *od += q[0];
      for (int64_t j = 0; j < stride; ++j) osh[j] += q[1 + j];
    }
  }
  for (auto& k : sinks)
    for (int64_t m : k.rows) k.slot[m] = -1;
}

// ---------------------------------------------------------------------------- dispatch and bindings
Params make_params(const torch::Tensor& bounds, double step, double scale, double stop, const torch::Tensor& sh,
                   bool has_act) {
  Params P;
  auto b = bounds.to(torch::kFloat64).contiguous();
  for (int a = 0; a < 3; ++a) P.hi[a] = b.data_ptr<double>()[3 + a];
  P.step = step; P.scale = scale; P.stop = stop;
  P.stride = sh.size(1) * 3;
  P.has_act = has_act;
  return P;
}

Grid make_grid(const torch::Tensor& index, const torch::Tensor& cell_live, const torch::Tensor& block_dist,
               const torch::Tensor& bounds, int64_t shift) {
  TORCH_CHECK(index.dim() == 3 && index.scalar_type() == torch::kInt32 && index.is_contiguous(), "index");
  TORCH_CHECK(cell_live.numel() == index.numel(), "cell_live must have the index volume's shape");
  Grid G;
  G.index = index.data_ptr<int32_t>();
  G.cell_live = cell_live.data_ptr<uint8_t>();
  G.block_dist = block_dist.data_ptr<uint8_t>();
  G.shift = int(shift);
  auto b = bounds.to(torch::kFloat64).contiguous();
  const double* bp = b.data_ptr<double>();
  for (int a = 0; a < 3; ++a) {
    G.R[a] = index.size(a);
    TORCH_CHECK(G.R[a] >= 2, "grid sides must be >= 2");
    G.B[a] = plx::num_blocks(G.R[a], int(shift));
    TORCH_CHECK(block_dist.size(a) == G.B[a], "block_dist has the wrong shape");
    G.lo[a] = bp[a];
    G.vs[a] = (bp[3 + a] - bp[a]) / double(G.R[a] - 1);
  }
  return G;
}

template <typename F>
void with_degree(int64_t degree, F&& f) {
  switch (degree) {
    case 0: f(std::integral_constant<int, 0>()); break;
    case 1: f(std::integral_constant<int, 1>()); break;
    case 2: f(std::integral_constant<int, 2>()); break;
    case 3: f(std::integral_constant<int, 3>()); break;
    default: TORCH_CHECK(false, "SH degree must be 0..3, got ", degree);
  }
}

}  // namespace

// Live masks of the grid for density `dens` [M] (live.h): cell_live [X, Y, Z] and block_dist [BX, BY, BZ]
// (uint8); `coords` [M, 3] long are the grid coordinates of the rows.
std::vector<at::Tensor> plx::live(const at::Tensor& index, const at::Tensor& coords, const at::Tensor& dens,
                                  int64_t shift) {
  TORCH_CHECK(index.dim() == 3 && index.scalar_type() == torch::kInt32 && index.is_contiguous(), "index");
  const int64_t R[3] = {index.size(0), index.size(1), index.size(2)};
  const int64_t B[3] = {plx::num_blocks(R[0], int(shift)), plx::num_blocks(R[1], int(shift)),
                        plx::num_blocks(R[2], int(shift))};
  auto opts = torch::TensorOptions().dtype(torch::kUInt8);
  auto cell = torch::zeros({R[0], R[1], R[2]}, opts);
  auto dist = torch::empty({B[0], B[1], B[2]}, opts);
  auto c = coords.to(torch::kInt64).contiguous();
  const int64_t M = dens.numel();
  TORCH_CHECK(c.size(0) == M, "coords and density must have one row per stored point");
  AT_DISPATCH_FLOATING_TYPES(dens.scalar_type(), "plx_live", [&] {
    const scalar_t* d = dens.data_ptr<scalar_t>();
    if (M * 8 < index.numel())
      plx::cells_from_points(c.data_ptr<int64_t>(), d, M, R, cell.data_ptr<uint8_t>());
    else
      plx::cells_from_volume(index.data_ptr<int32_t>(), d, R, cell.data_ptr<uint8_t>());
  });
  plx::block_distance(cell.data_ptr<uint8_t>(), R, int(shift), B, dist.data_ptr<uint8_t>());
  return {cell, dist};
}

plx::Marched plx::march_forward(const Rays& rays, const VoxelGrid& grid, const Field& f) {
  const at::Tensor &ro = rays.origins, &rd = rays.directions;
  Params P = make_params(grid.bounds, rays.step, rays.scale, rays.stop, f.sh, f.act);
  Grid G = make_grid(grid.index, grid.cell_live, grid.block_dist, grid.bounds, grid.shift);
  int64_t R = ro.size(0);
  Marched out;
  out.rgb = torch::zeros({R, 3}, ro.options());
  out.alpha = torch::zeros({R}, ro.options());
  out.wt = torch::zeros({R}, ro.options());
  out.mom = torch::zeros({R, 2}, ro.options());
  AT_DISPATCH_FLOATING_TYPES(ro.scalar_type(), "plx_forward", [&] {
    with_degree(f.degree, [&](auto deg) {
      forward_impl<scalar_t, decltype(deg)::value>(
          P, G, ro.data_ptr<scalar_t>(), rd.data_ptr<scalar_t>(), f.density.data_ptr<scalar_t>(),
          f.sh.data_ptr<scalar_t>(), f.act ? f.act_w.data_ptr<scalar_t>() : nullptr,
          f.act ? f.act_b.data_ptr<scalar_t>() : nullptr, R, out.rgb.data_ptr<scalar_t>(),
          out.alpha.data_ptr<scalar_t>(), out.wt.data_ptr<scalar_t>(), out.mom.data_ptr<scalar_t>());
    });
  });
  return out;
}

// The rows the rays touched, sorted, with their density and SH gradients; the per-ray ACT gradients. slots [B, M]
// int32 are -1 on entry and on return, one row of them per thread (B = the number of OpenMP threads): each
// thread's rows and sums are its own (cell.h).
plx::FieldGrads plx::march_backward(const Rays& rays, const VoxelGrid& grid, const Field& f, const Marched& fwd,
                                    const Marched& g, const at::Tensor& slots) {
  const at::Tensor &ro = rays.origins, &rd = rays.directions, &dens = f.density, &sh = f.sh;
  Params P = make_params(grid.bounds, rays.step, rays.scale, rays.stop, sh, f.act);
  Grid G = make_grid(grid.index, grid.cell_live, grid.block_dist, grid.bounds, grid.shift);
  const int64_t R = ro.size(0), M = dens.numel();
  const int nt = std::max(1, omp_get_max_threads());
  TORCH_CHECK(slots.dim() == 2 && slots.size(0) == nt && slots.size(1) == M && slots.scalar_type() == torch::kInt32 &&
              slots.is_contiguous(), "backward: slots must be int32 [threads (", nt, "), M]");
  FieldGrads out;
  out.act_w = torch::zeros({R, 3}, ro.options());
  out.act_b = torch::zeros({R, 3}, ro.options());
  AT_DISPATCH_FLOATING_TYPES(ro.scalar_type(), "plx_backward", [&] {
    std::vector<Sink<scalar_t>> sinks(nt);
    for (int b = 0; b < nt; ++b) {
      sinks[b].slot = slots.data_ptr<int32_t>() + b * M;
      sinks[b].width = 1 + P.stride;
    }
    with_degree(f.degree, [&](auto deg) {
      backward_impl<scalar_t, decltype(deg)::value>(
          P, G, ro.data_ptr<scalar_t>(), rd.data_ptr<scalar_t>(), dens.data_ptr<scalar_t>(), sh.data_ptr<scalar_t>(),
          f.act ? f.act_w.data_ptr<scalar_t>() : nullptr, f.act ? f.act_b.data_ptr<scalar_t>() : nullptr, R,
          fwd.rgb.data_ptr<scalar_t>(), fwd.alpha.data_ptr<scalar_t>(), fwd.wt.data_ptr<scalar_t>(),
          fwd.mom.data_ptr<scalar_t>(), g.rgb.data_ptr<scalar_t>(), g.alpha.data_ptr<scalar_t>(),
          g.wt.data_ptr<scalar_t>(), g.mom.data_ptr<scalar_t>(), sinks, out.act_w.data_ptr<scalar_t>(),
          out.act_b.data_ptr<scalar_t>());
    });
    std::vector<int64_t> rows = touched_rows(sinks, M);
    const int64_t n = int64_t(rows.size());
    out.rows = torch::from_blob(rows.data(), {n}, torch::kInt64).clone();
    out.density = torch::empty({n}, dens.options());
    out.sh = torch::empty({n, sh.size(1), sh.size(2)}, sh.options());
    collect<scalar_t>(rows, sinks, P.stride, out.density.data_ptr<scalar_t>(), out.sh.data_ptr<scalar_t>());
  });
  return out;
}

at::Tensor plx::max_weights(const Rays& rays, const VoxelGrid& grid, const Field& f) {
  const at::Tensor &ro = rays.origins, &rd = rays.directions, &dens = f.density;
  Params P = make_params(grid.bounds, rays.step, rays.scale, rays.stop, dens.view({-1, 1, 1}), false);
  Grid G = make_grid(grid.index, grid.cell_live, grid.block_dist, grid.bounds, grid.shift);
  auto best = torch::zeros_like(dens);
  AT_DISPATCH_FLOATING_TYPES(ro.scalar_type(), "plx_max_weights", [&] {
    max_weights_impl<scalar_t, 0>(P, G, ro.data_ptr<scalar_t>(), rd.data_ptr<scalar_t>(), dens.data_ptr<scalar_t>(),
                                  ro.size(0), best.data_ptr<scalar_t>(), dens.numel());
  });
  return best;
}
