// Screen footprints (no gradient) and tile binning of 2DGS / 3DGS splats, fused.
//
// Ports of the PyTorch reference functions (same double arithmetic, same results):
//   footprint2d: backbones/gs2d/render.py footprint_2dgs (+ raster.tile_rects, effective_cutoff2)
//   footprint3d: backbones/gs3d/render.py footprint_3dgs
//   binning:     backbones/gaussians/raster.py bin_tiles -> offsets [C*TY*TX+1], ids [P] sorted by tile,
//                then by (depth, index) within the tile (the torch stable argsort rank); and, per entry,
//                the positions of its pairs (tile order), the fixed order in which the kernels sum gradients.
// Inputs are flattened (camera, splat) entries s = c * N + n; opacities are per splat n.
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <type_traits>
#include <vector>

#include "api.h"
#include "pool.h"
#include "project.h"

namespace arcsem {
namespace {

constexpr int64_t kGrain = 1 << 14;  // splats per chunk of the per-splat loops

inline double cutoff2(double op) {  // raster.effective_cutoff2
  const double c2 = 2.0 * std::log(255.0 * std::max(op, 1e-30));
  return c2 * (1 + 1e-4) + 1e-4;
}

inline double clampd(double v, double lo, double hi) { return std::isnan(v) ? v : std::min(std::max(v, lo), hi); }
inline int64_t to_long(double v) { return std::isfinite(v) ? int64_t(v) : std::numeric_limits<int64_t>::min(); }

struct Screen {
  int64_t W, H, tile, TX, TY;
};

// raster.tile_rects: rect (tx0, tx1, ty0, ty1), upper bounds exclusive
inline void tile_rect(const Screen& sc, double cx, double cy, int64_t radius, int64_t* rect) {
  const bool ok = radius > 0;
  const double c[2] = {(ok ? cx : 0.0) - 0.5, (ok ? cy : 0.0) - 0.5};
  const double r = double(radius), big = 4.0 * double(sc.W + sc.H + sc.tile);
  const int64_t lim[2] = {sc.TX, sc.TY};
  for (int a = 0; a < 2; ++a) {
    const int64_t lo = to_long(std::floor(clampd((c[a] - r) / double(sc.tile), -big, big)));
    const int64_t hi = to_long(std::floor(clampd((c[a] + r + double(sc.tile) - 1) / double(sc.tile), -big, big)));
    const int64_t l = std::min(std::max(lo, int64_t(0)), lim[a]);
    const int64_t h = std::min(std::max(hi, int64_t(0)), lim[a]);
    rect[2 * a] = l;
    rect[2 * a + 1] = ok ? h : l;
  }
}

// inclusive pixel-index box from float bounds (gs2d render._pixel_box / the gs3d equivalent)
inline void pixel_box(const Screen& sc, const double lo[2], const double hi[2], bool ok, int64_t* box) {
  const double m = double(std::max(sc.W, sc.H) + 1);
  const int64_t lim[2] = {sc.W - 1, sc.H - 1};
  for (int a = 0; a < 2; ++a) {
    box[2 * a] = std::max(to_long(std::ceil(clampd(lo[a] - 0.5, -1, m))), int64_t(0));
    box[2 * a + 1] = std::min(to_long(std::floor(clampd(hi[a] - 0.5, -2, m))), lim[a]);
  }
  if (!ok) box[1] = -1;
}

// gs2d render._conic_box on kL splats at once (lane vectors): bounding box (centre c, half extents e) of the image
// of the disk u^2 + v^2 <= cut2 under rows T[0..2], valid where d22 < 0
inline void conic_box_lanes(const proj::Lanes* T, proj::Lanes cut2, proj::Lanes c[2], proj::Lanes e[2],
                            proj::Lanes& d22) {
  using proj::Lanes;
  const Lanes f[3] = {proj::splat(1.0), proj::splat(1.0), -1.0 / cut2};
  auto D = [&](int i, int j) {
    Lanes acc = proj::splat(0.0);
    for (int k = 0; k < 3; ++k) acc += T[3 * i + k] * f[k] * T[3 * j + k];
    return acc;
  };
  const Lanes D00 = D(0, 0), D02 = D(0, 2), D11 = D(1, 1), D12 = D(1, 2);
  d22 = D(2, 2);
  const Lanes den = d22 < 0 ? d22 : proj::splat(1.0), lo = proj::splat(1e-4);
  c[0] = D02 / den;
  c[1] = D12 / den;
  const Lanes q0 = c[0] * c[0] - D00 / den, q1 = c[1] * c[1] - D11 / den;
  e[0] = proj::vsqrt(q0 < lo ? lo : q0);  // std::max(q, 1e-4): NaN stays NaN
  e[1] = proj::vsqrt(q1 < lo ? lo : q1);
}

// footprint2d: the floating-point part (both conic boxes, the centre) on lane vectors of kL splats, the integer
// rectangles and boxes per splat
template <typename T>
void footprint2d_impl(const T* Hm, const T* Dz, const T* op, int64_t M, int64_t N, double near, double sigma,
                      const Screen& sc, int64_t* radius, int64_t* rects, int64_t* eff, T* depth) {
  using proj::Lanes;
  using proj::kL;
  parallel_range(M, kGrain, [&](int64_t b, int64_t e, int) {
    for (int64_t s0 = b; s0 < e; s0 += kL) {
      const int nb = int(std::min<int64_t>(kL, e - s0));
      Lanes Td[12], cut2;
      for (int i = 0; i < kL; ++i) {  // lanes past the range repeat its last splat (not written)
        const int64_t s = s0 + std::min(i, nb - 1);
        for (int j = 0; j < 9; ++j) Td[j][i] = double(Hm[9 * s + j]);
        for (int j = 0; j < 3; ++j) Td[9 + j][i] = double(Dz[3 * s + j]);
        cut2[i] = cutoff2(double(op[s % N]));
      }
      const Lanes cx = Td[2] / Td[8], cy = Td[5] / Td[8], small = proj::splat(1e-6), zero = proj::splat(0.0);
      Lanes c3[2], e3[2], ce[2], ee[2], d3, de;
      conic_box_lanes(Td, proj::splat(9.0), c3, e3, d3);
      conic_box_lanes(Td, cut2 < small ? small : cut2, ce, ee, de);
      const Lanes r2d = proj::vsqrt(cut2 < zero ? zero : cut2) * sigma;
      for (int i = 0; i < nb; ++i) {
        const int64_t s = s0 + i;
        const double z = Td[11][i];
        const bool ok = d3[i] < 0 && z > near && std::isfinite(e3[0][i]) && std::isfinite(e3[1][i]);
        const double r = std::ceil(std::max(std::max(e3[0][i], e3[1][i]), 3.0 * sigma));
        radius[s] = ok ? int64_t(std::min(r, 1e7)) : 0;
        tile_rect(sc, c3[0][i], c3[1][i], radius[s], rects + 4 * s);
        const bool oke = de[i] < 0;
        const double inf = std::numeric_limits<double>::infinity();
        const double lo[2] = {std::min(oke ? ce[0][i] - ee[0][i] : -inf, cx[i] - r2d[i]) - 0.01,
                              std::min(oke ? ce[1][i] - ee[1][i] : -inf, cy[i] - r2d[i]) - 0.01};
        const double hi[2] = {std::max(oke ? ce[0][i] + ee[0][i] : inf, cx[i] + r2d[i]) + 0.01,
                              std::max(oke ? ce[1][i] + ee[1][i] : inf, cy[i] + r2d[i]) + 0.01};
        pixel_box(sc, lo, hi, cut2[i] > 0, eff + 4 * s);
        depth[s] = T(z);  // exact: z is a value of type T
      }
    }
  });
}

template <typename T>
void footprint3d_impl(const T* m2d, const T* dep, const T* cov, const T* op, int64_t M, int64_t N, double near,
                      const Screen& sc, int64_t* radius, int64_t* rects, int64_t* eff, bool* okout) {
  parallel_range(M, kGrain, [&](int64_t b, int64_t e, int) {
    for (int64_t s = b; s < e; ++s) {
      const double a = cov[3 * s], bb = cov[3 * s + 1], c = cov[3 * s + 2];
      const double det = a * c - bb * bb, mid = 0.5 * (a + c);
      const double lam = mid + std::sqrt(std::max(mid * mid - det, 0.1));
      const bool ok = det > 0 && dep[s] > T(near) && std::isfinite(lam);
      radius[s] = ok ? int64_t(std::min(std::ceil(3 * std::sqrt(std::max(lam, 0.0))), 1e7)) : 0;
      const double mx = double(m2d[2 * s]), my = double(m2d[2 * s + 1]);
      tile_rect(sc, mx, my, radius[s], rects + 4 * s);
      const double cut2 = cutoff2(double(op[s % N])), c2 = std::max(cut2, 0.0);
      const double hx = std::sqrt(c2 * a) * 1.001 + 0.01, hy = std::sqrt(c2 * c) * 1.001 + 0.01;
      const double lo[2] = {mx - hx, my - hy}, hi[2] = {mx + hx, my + hy};
      pixel_box(sc, lo, hi, cut2 > 0, eff + 4 * s);
      okout[s] = ok;
    }
  });
}

// a float / double as an unsigned key of its width with the same order (-0 = +0; NaN last, as torch.argsort)
template <typename D>
inline std::conditional_t<sizeof(D) == 4, uint32_t, uint64_t> sort_key(D d) {
  using K = std::conditional_t<sizeof(D) == 4, uint32_t, uint64_t>;
  constexpr int top = 8 * sizeof(K) - 1;
  if (std::isnan(d)) return ~K(0);
  if (d == D(0)) d = D(0);
  K b;
  std::memcpy(&b, &d, sizeof b);
  return (b >> top) ? ~b : b | (K(1) << top);
}

// the entries that have tiles, by depth (ties: index order): a stable LSD radix sort, 11 bits a pass, on keys as
// wide as the depth's type (float depths: 3 passes, not 6) and 32-bit entry indices
template <typename D>
std::vector<int32_t> depth_order(const D* depth, const int64_t* rects, int64_t M) {
  using K = decltype(sort_key(D(0)));
  TORCH_CHECK(M < (int64_t(1) << 31), "tile binning: at most 2^31 - 1 (camera, splat) entries");
  std::vector<K> key, key2;
  std::vector<int32_t> idx, idx2;
  key.reserve(size_t(M));
  idx.reserve(size_t(M));
  for (int64_t s = 0; s < M; ++s) {
    const int64_t* r = rects + 4 * s;
    if (r[1] > r[0] && r[3] > r[2]) {
      key.push_back(sort_key(depth[s]));
      idx.push_back(int32_t(s));
    }
  }
  const size_t n = key.size();
  key2.resize(n);
  idx2.resize(n);
  for (int shift = 0; shift < int(8 * sizeof(K)); shift += 11) {
    size_t count[2049] = {0};
    for (const K k : key) ++count[((k >> shift) & 2047) + 1];
    if (count[((key.empty() ? 0 : key[0] >> shift) & 2047) + 1] == n) continue;  // one digit value: nothing moves
    for (int b = 0; b < 2048; ++b) count[b + 1] += count[b];
    for (size_t i = 0; i < n; ++i) {
      const size_t at = count[(key[i] >> shift) & 2047]++;
      key2[at] = key[i];
      idx2[at] = idx[i];
    }
    key.swap(key2);
    idx.swap(idx2);
  }
  return idx;
}

// raster.bin_tiles: pairs sorted by camera-tile, then by (depth, splat index); and per entry its pairs
template <typename D>
void bin_impl(const int64_t* rects, const D* depth, int64_t C, int64_t N, const Screen& sc, TileLists& out) {
  const int64_t M = C * N, TT = sc.TX * sc.TY;
  auto lo = out.rects.options();
  out.offsets = at::zeros({C * TT + 1}, lo);
  out.entry_offsets = at::empty({M + 1}, lo);
  int64_t* off = out.offsets.data_ptr<int64_t>();
  int64_t* eoff = out.entry_offsets.data_ptr<int64_t>();
  std::vector<int32_t> order;
  parallel_chunks(2, [&](int64_t part, int) {  // the depth order beside the pair counts
    if (part == 0) {
      order = depth_order(depth, rects, M);
      return;
    }
    eoff[0] = 0;
    for (int64_t s = 0; s < M; ++s) {
      const int64_t* r = rects + 4 * s;
      const int64_t base = (s / N) * TT;
      for (int64_t ty = r[2]; ty < r[3]; ++ty)
        for (int64_t tx = r[0]; tx < r[1]; ++tx) ++off[base + ty * sc.TX + tx + 1];
      eoff[s + 1] = eoff[s] + std::max<int64_t>(r[1] - r[0], 0) * std::max<int64_t>(r[3] - r[2], 0);
    }
    for (int64_t t = 0; t < C * TT; ++t) off[t + 1] += off[t];
  });
  out.ids = at::empty({off[C * TT]}, lo);
  out.pair_of = at::empty({off[C * TT]}, lo);
  int64_t* ids = out.ids.data_ptr<int64_t>();
  int64_t* pof = out.pair_of.data_ptr<int64_t>();
  // the pairs in depth order (ties: index) per tile by construction; each worker fills the tiles of an equal
  // share of the pairs and reads all entries
  const int64_t P = off[C * TT];
  const int parts = num_workers(std::max<int64_t>(P / 16384, 1));
  parallel_chunks(parts, [&](int64_t part, int) {
    const int64_t t0 = std::lower_bound(off, off + C * TT, P * part / parts) - off;
    const int64_t t1 = part + 1 == parts ? C * TT : std::lower_bound(off, off + C * TT, P * (part + 1) / parts) - off;
    std::vector<int64_t> cur(off + t0, off + t1);
    for (size_t i = 0; i < order.size(); ++i) {
      if (i + 16 < order.size()) {  // the entries come in depth order, scattered in memory: ask for them ahead
        __builtin_prefetch(rects + 4 * order[i + 16]);
        __builtin_prefetch(eoff + order[i + 16]);
      }
      const int64_t s = order[i];
      const int64_t* r = rects + 4 * s;
      const int64_t base = (s / N) * TT;
      if (base + r[2] * sc.TX + r[0] >= t1 || base + (r[3] - 1) * sc.TX + r[1] <= t0) continue;  // none of mine
      int64_t k = eoff[s];
      for (int64_t ty = r[2]; ty < r[3]; ++ty)
        for (int64_t tx = r[0]; tx < r[1]; ++tx, ++k) {
          const int64_t t = base + ty * sc.TX + tx;
          if (t < t0 || t >= t1) continue;
          const int64_t p = cur[t - t0]++;
          ids[p] = s;
          pof[k] = p;
        }
    }
  });
}

// render._outputs: visible = radius > 0 and a non-empty tile rectangle; radii zeroed where not visible
at::Tensor visibility(at::Tensor& radius, const at::Tensor& rects) {
  auto vis = at::empty({radius.numel()}, radius.options().dtype(at::kBool));
  int64_t* r = radius.data_ptr<int64_t>();
  const int64_t* rc = rects.data_ptr<int64_t>();
  bool* v = vis.data_ptr<bool>();
  for (int64_t s = 0; s < radius.numel(); ++s) {
    v[s] = r[s] > 0 && rc[4 * s + 1] > rc[4 * s] && rc[4 * s + 3] > rc[4 * s + 2];
    if (!v[s]) r[s] = 0;
  }
  return vis;
}

Screen screen(const Raster& r) {
  return Screen{r.W, r.H, r.tile, (r.W + r.tile - 1) / r.tile, (r.H + r.tile - 1) / r.tile};
}

void check(const at::Tensor& t, const char* name) {
  TORCH_CHECK(t.is_contiguous() && t.device().is_cpu(), name, " must be a contiguous CPU tensor");
}

TileLists allocate(int64_t M, const at::TensorOptions& lo) {
  TileLists l;
  l.radii = at::empty({M}, lo);
  l.rects = at::empty({M, 4}, lo);
  l.box = at::empty({M, 4}, lo);
  return l;
}

}  // namespace

TileLists footprint_bin2d(const at::Tensor& Hm, const at::Tensor& Dz, const at::Tensor& op, const Raster& raster,
                          double near, double sigma) {
  check(Hm, "homographies"); check(Dz, "depth rows"); check(op, "opacities");
  const int64_t M = Hm.size(0), N = op.numel(), C = raster.C;
  TORCH_CHECK(M == C * N && Hm.size(1) == 9 && Dz.size(1) == 3, "footprint_bin2d: Hm, Dz must be [C*N, 9], [C*N, 3]");
  TORCH_CHECK(sigma > 0, "footprint_bin2d: the low-pass sigma must be > 0");
  const Screen sc = screen(raster);
  TileLists l = allocate(M, Hm.options().dtype(at::kLong));
  auto depth = at::empty({M}, Hm.options());  // (the centre's depth Dz.z: a value of the input's type)
  AT_DISPATCH_FLOATING_TYPES(Hm.scalar_type(), "footprint2d", [&] {
    footprint2d_impl<scalar_t>(Hm.data_ptr<scalar_t>(), Dz.data_ptr<scalar_t>(), op.data_ptr<scalar_t>(), M, N, near, sigma, sc,
                               l.radii.data_ptr<int64_t>(), l.rects.data_ptr<int64_t>(), l.box.data_ptr<int64_t>(),
                               depth.data_ptr<scalar_t>());
    bin_impl<scalar_t>(l.rects.data_ptr<int64_t>(), depth.data_ptr<scalar_t>(), C, N, sc, l);
  });
  l.visible = visibility(l.radii, l.rects);
  return l;
}

TileLists footprint_bin3d(const at::Tensor& m2d, const at::Tensor& depth, const at::Tensor& cov,
                          const at::Tensor& op, const Raster& raster, double near) {
  for (auto* t : {&m2d, &depth, &cov, &op}) check(*t, "footprint_bin3d input");
  const int64_t M = depth.numel(), N = op.numel(), C = raster.C;
  TORCH_CHECK(M == C * N, "footprint_bin3d: depth must have C*N entries");
  const Screen sc = screen(raster);
  TileLists l = allocate(M, depth.options().dtype(at::kLong));
  auto ok = at::empty({M}, depth.options().dtype(at::kBool));
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "footprint3d", [&] {
    footprint3d_impl<scalar_t>(m2d.data_ptr<scalar_t>(), depth.data_ptr<scalar_t>(), cov.data_ptr<scalar_t>(),
                               op.data_ptr<scalar_t>(), M, N, near, sc, l.radii.data_ptr<int64_t>(),
                               l.rects.data_ptr<int64_t>(), l.box.data_ptr<int64_t>(), ok.data_ptr<bool>());
    bin_impl<scalar_t>(l.rects.data_ptr<int64_t>(), depth.data_ptr<scalar_t>(), C, N, sc, l);
  });
  l.visible = visibility(l.radii, l.rects);
  return l;
}

}  // namespace arcsem
