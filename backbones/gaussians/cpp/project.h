// What the fused projections of 2DGS surfels (project.cpp) and 3DGS ellipsoids (project3d.cpp) share: lane vectors,
// the rotation of a quaternion and its vector-Jacobian product, one splat's parameters with its rotation.
//
// Ports of the differentiable PyTorch reference code, evaluated in double and stored in the input type, on kL splats
// at once: every value of the per-splat arithmetic is a lane vector (Lanes, a GCC/Clang vector of doubles), so the
// compiler emits vector instructions for all of it (an `omp simd` loop over the splats did not vectorise: its
// per-splat arrays stayed in memory).
// P [C, 4, 4] is raster_camera.pixel_projection: world -> (x w, y w, w, z). Entries s = c * N + n.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "api.h"

namespace arcsem {
namespace proj {

constexpr int64_t kGrain = 1 << 13;  // splats per chunk of the per-splat loops
constexpr int kL = 8;                 // splats a lane vector holds (8 doubles: one AVX-512 register, two AVX2)
typedef double Lanes __attribute__((vector_size(8 * kL)));

typedef int64_t Mask __attribute__((vector_size(8 * kL)));  // a comparison of Lanes: -1 (true) or 0 per lane
typedef float LanesF __attribute__((vector_size(4 * kL)));

inline Lanes splat(double x) { return Lanes{} + x; }

inline Lanes vsqrt(Lanes x) {
  for (int i = 0; i < kL; ++i) x[i] = std::sqrt(x[i]);
  return x;
}

// x rounded to the storage type T and back (the reference computes from stored values)
template <typename T>
inline Lanes stored(Lanes x) {
  if constexpr (std::is_same_v<T, float>) return __builtin_convertvector(__builtin_convertvector(x, LanesF), Lanes);
  else return x;
}

// raster_camera.quat_to_rotmat (row-major R[3 * i + j]) and its vector-Jacobian product
inline void rotmat(const Lanes q[4], Lanes R[9], Lanes qn[4], Lanes& norm) {
  norm = vsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int i = 0; i < 4; ++i) qn[i] = q[i] / norm;
  const Lanes w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z); R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z); R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y); R[7] = 2 * (y * z + w * x); R[8] = 1 - 2 * (x * x + y * y);
}

inline void rotmat_vjp(const Lanes qn[4], Lanes norm, const Lanes g[9], Lanes gq[4]) {
  const Lanes w = qn[0], x = qn[1], y = qn[2], z = qn[3];
  Lanes gn[4];
  gn[0] = 2 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
  gn[1] = 2 * (y * g[1] + z * g[2] + y * g[3] - 2 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2 * x * g[8]);
  gn[2] = 2 * (-2 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2 * y * g[8]);
  gn[3] = 2 * (-2 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2 * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
  const Lanes dot = gn[0] * w + gn[1] * x + gn[2] * y + gn[3] * z;
  for (int i = 0; i < 4; ++i) gq[i] = (gn[i] - qn[i] * dot) / norm;
}

struct Splat {  // kL splats' parameters, with their rotations
  Lanes m[3], q[4], s[3], R[9], qn[4], norm;
  Splat(const Lanes* mean, const Lanes* quat, const Lanes* scale) {
    for (int i = 0; i < 3; ++i) m[i] = mean[i];
    for (int i = 0; i < 4; ++i) q[i] = quat[i];
    for (int i = 0; i < 3; ++i) s[i] = scale[i];
    rotmat(q, R, qn, norm);
  }
};

// splats n0 .. n0 + nb - 1 (means [N, 3], quats [N, 4], scales [N, ns]) as lane vectors: scales past ns are 0;
// lanes past nb repeat the last splat (they are not written)
template <typename T>
Splat load_splats(const T* m, const T* q, const T* sc, int ns, int64_t n0, int nb) {
  Lanes in[10] = {};
  for (int i = 0; i < kL; ++i) {
    const int64_t n = n0 + std::min(i, nb - 1);
    for (int j = 0; j < 3; ++j) in[j][i] = m[3 * n + j];
    for (int j = 0; j < 4; ++j) in[3 + j][i] = q[4 * n + j];
    for (int j = 0; j < ns; ++j) in[7 + j][i] = sc[ns * n + j];
  }
  return Splat(in, in + 3, in + 7);
}

// the gradients of splats n0 .. n0 + nb - 1 from those of their rotation (gR [9]), means and scales (ns of them):
// g_means [N, 3], g_quats [N, 4] (through the normalisation), g_scales [N, ns]
template <typename T>
void store_splat_grads(const Splat& sp, const Lanes* gR, const Lanes* gmean, const Lanes* gscale, int ns,
                       int64_t n0, int nb, T* om, T* oq, T* os) {
  Lanes gquat[4];
  rotmat_vjp(sp.qn, sp.norm, gR, gquat);
  for (int i = 0; i < nb; ++i) {
    const int64_t n = n0 + i;
    for (int j = 0; j < 3; ++j) om[3 * n + j] = T(gmean[j][i]);
    for (int j = 0; j < 4; ++j) oq[4 * n + j] = T(gquat[j][i]);
    for (int j = 0; j < ns; ++j) os[ns * n + j] = T(gscale[j][i]);
  }
}

inline void check(const at::Tensor& t) {
  TORCH_CHECK(t.is_contiguous() && t.device().is_cpu(), "project: inputs must be contiguous CPU tensors");
}

}  // namespace proj
}  // namespace arcsem
