// Shared pieces of the fused Plenoxels ray marcher (render.cpp): SH basis, the grid view, one ray's sample
// range, and the traversal that visits only samples in live cells (empty-space skipping on a block mask).
//
// Sampling is render.py's (the PyTorch reference): segments of world length `step` partition the ray's part
// inside the box, [t_near, t_far]; sample s sits at the midpoint of segment s; grid coordinates are
// go + t * gd with go = (o - lo) / vs, gd = d / vs; the sample's cell is floor(g) clamped to [0, R - 2].
// A cell is live when one of its 8 corners is stored with a positive density: ReLU(trilinear) is 0
// elsewhere, so skipping dead cells changes nothing. Blocks of 2^shift cells are live when one of
// their cells is; a sample in a dead block at Chebyshev distance D from the nearest live block (live.h)
// jumps to the first sample past the cube of blocks of radius D - 1 around it.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace plx {

template <int DEG>
constexpr int num_coef() { return (DEG + 1) * (DEG + 1); }

// Real SH basis up to degree DEG at the unit direction (x, y, z) (the convention of arcsem's sh_basis).
template <typename T, int DEG>
inline void sh_basis(T x, T y, T z, T* b) {
  b[0] = T(0.28209479177387814);
  if constexpr (DEG >= 1) {
    const T C1 = T(0.4886025119029199);
    b[1] = -C1 * y; b[2] = C1 * z; b[3] = -C1 * x;
  }
  if constexpr (DEG >= 2) {
    b[4] = T(1.0925484305920792) * x * y;
    b[5] = T(-1.0925484305920792) * y * z;
    b[6] = T(0.31539156525252005) * (2 * z * z - x * x - y * y);
    b[7] = T(-1.0925484305920792) * x * z;
    b[8] = T(0.5462742152960396) * (x * x - y * y);
  }
  if constexpr (DEG >= 3) {
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

// What the traversal reads of a grid: the index volume, the live masks and the box.
struct Grid {
  const int32_t* index;      // [X, Y, Z] row of each grid point or -1
  const uint8_t* cell_live;  // [X, Y, Z] cell (lower corner i, j, k) has a stored corner with density > 0
  const uint8_t* block_dist; // [BX, BY, BZ] 0: a block of 2^shift cells per axis with a live cell, else the
                             // Chebyshev distance to the nearest live block (live.h)
  int64_t R[3], B[3];
  int shift;
  double lo[3], vs[3];
};

// One ray: its grid-space origin and direction, sample range and SH basis.
template <typename T, int DEG>
struct Ray {
  T go[3], gd[3], inv_gd[3];  // inv_gd: 0 where the ray is parallel to the axis
  T tn, tf, dt, dn;
  int64_t n;  // number of segments
  T basis[num_coef<DEG>()];
};

template <typename T, int DEG>
inline void setup_ray(const Grid& G, const double* hi, double step, const T* o, const T* d, Ray<T, DEG>& r) {
  T mx = T(0), mn = std::numeric_limits<T>::infinity();
  for (int a = 0; a < 3; ++a) {
    T da = std::abs(d[a]) < T(1e-12) ? T(1e-12) : d[a];
    T inv = T(1) / da;
    T t0 = (T(G.lo[a]) - o[a]) * inv, t1 = (T(hi[a]) - o[a]) * inv;
    mx = std::max(mx, std::min(t0, t1));
    mn = std::min(mn, std::max(t0, t1));
  }
  r.dn = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  r.tn = mx;
  r.tf = mn;
  r.dt = T(step) / r.dn;
  T n = std::ceil(std::max((r.tf - r.tn) / r.dt, T(0)) - T(1e-6));
  r.n = n > 0 ? int64_t(n) : 0;
  for (int a = 0; a < 3; ++a) {
    r.go[a] = (o[a] - T(G.lo[a])) / T(G.vs[a]);
    r.gd[a] = d[a] / T(G.vs[a]);
    r.inv_gd[a] = std::abs(r.gd[a]) < T(1e-20) ? T(0) : T(1) / r.gd[a];
  }
  sh_basis<T, DEG>(d[0] / r.dn, d[1] / r.dn, d[2] / r.dn, r.basis);
}

// One visited sample: segment, midpoint t, cell (linear index of its lower corner) and the fractions in it.
template <typename T>
struct Sample {
  int64_t s, lin;
  T tm, delta, f[3];
};

// First sample index past the cube of dead blocks of radius D - 1 around the block of cell b (at least
// s + 1): the cube's exit t along the ray, less 1 % of a segment so that rounding never skips a live sample.
template <typename T, int DEG>
inline int64_t skip_blocks(const Grid& G, const Ray<T, DEG>& r, const int64_t* b, int D, int64_t s) {
  T t_exit = std::numeric_limits<T>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (r.inv_gd[a] == 0) continue;
    int64_t blk = b[a] >> G.shift;
    T face = T(r.gd[a] > 0 ? (blk + D) << G.shift : (blk - D + 1) << G.shift);
    t_exit = std::min(t_exit, (face - r.go[a]) * r.inv_gd[a]);
  }
  T x = std::ceil((t_exit - r.tn) / r.dt - T(0.51));
  if (!(x < T(r.n))) return r.n;
  return std::max(s + 1, int64_t(x));
}

// Calls visit(sample) for every sample of the ray in a live cell, front to back; visit returns false to stop.
template <typename T, int DEG, typename F>
inline void march(const Grid& G, const Ray<T, DEG>& r, F&& visit) {
  const int64_t Y = G.R[1], Z = G.R[2];
  Sample<T> smp;
  int64_t b[3];
  for (int64_t s = 0; s < r.n;) {
    T t0 = r.tn + T(s) * r.dt;
    T delta = std::min(std::max(r.tf - t0, T(0)), r.dt);
    T tm = t0 + T(0.5) * delta;
    for (int a = 0; a < 3; ++a) {
      T g = std::min(std::max(r.go[a] + tm * r.gd[a], T(0)), T(G.R[a] - 1));
      b[a] = std::min(int64_t(g), G.R[a] - 2);  // g >= 0: truncation is floor
      smp.f[a] = g - T(b[a]);
    }
    int64_t blk = ((b[0] >> G.shift) * G.B[1] + (b[1] >> G.shift)) * G.B[2] + (b[2] >> G.shift);
    if (const int D = G.block_dist[blk]) {
      s = skip_blocks<T, DEG>(G, r, b, D, s);
      continue;
    }
    smp.lin = (b[0] * Y + b[1]) * Z + b[2];
    if (G.cell_live[smp.lin]) {
      smp.s = s;
      smp.tm = tm;
      smp.delta = delta;
      if (!visit(smp)) return;
    }
    ++s;
  }
}

}  // namespace plx
