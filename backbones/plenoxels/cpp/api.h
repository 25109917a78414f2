// Every kernel of the fused Plenoxels marcher that Python calls (backbones/plenoxels/fused.py), with its arguments
// named and grouped like the Gaussian kernels' (backbones/gaussians/cpp/api.h): module.cpp binds these declarations
// and the structs (their fields are set by name from Python), render.cpp defines them.
//
// R rays, M stored points (rows of the sparse grid), K SH coefficients stored per point and channel.
#pragma once
// ATen's tensor only (render.cpp includes torch/extension.h for its kernels; module.cpp, pybind11)
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <vector>

namespace plx {

// The sparse grid and its live masks (live(): cells with a stored corner of positive density, and per block of
// 2^shift cells a side the Chebyshev distance in blocks to the nearest live block; live.h).
struct VoxelGrid {
  at::Tensor index;       // [X, Y, Z] int32: the row of each vertex, -1 where none is stored
  at::Tensor cell_live;   // [X, Y, Z] uint8
  at::Tensor block_dist;  // [BX, BY, BZ] uint8, BX = (X - 2) / 2^shift + 1
  at::Tensor bounds;      // [2, 3] the grid's box: lo, hi (world)
  int64_t shift = 2;      // blocks of 2^shift cells a side
};

// What the rays see: density and SH at the stored points, and each ray's ACT colour transform.
struct Field {
  at::Tensor density;       // [M]
  at::Tensor sh;            // [M, K, 3]
  int64_t degree = 0;       // SH degree 0..3 (K >= (degree + 1)^2)
  bool act = false;         // apply act_w, act_b (clamp(act_w v + act_b, 0, 1) per sample colour v)
  at::Tensor act_w, act_b;  // [R, 3], or empty without ACT
};

// The rays and their sampling (march.h): segments of world length `step` inside the box; a sample's optical
// depth is relu(sigma) * delta * |d| / scale (delta: its segment in t); a ray ends once its transmittance falls
// below `stop`.
struct Rays {
  at::Tensor origins;     // [R, 3]
  at::Tensor directions;  // [R, 3]
  double step = 0.0;
  double scale = 1.0;
  double stop = 1e-4;
};

// The outputs of a march per ray, or (backward) their gradients.
struct Marched {
  at::Tensor rgb;    // [R, 3] sum w c (no background)
  at::Tensor alpha;  // [R] sum w
  at::Tensor wt;     // [R] sum w t
  at::Tensor mom;    // [R, 2] sum w u, sum w u^2 with u = t - t_near (the distortion's moments)
};

// Gradients of a march: of density and SH over the n rows the rays touched, and of each ray's ACT transform.
struct FieldGrads {
  at::Tensor rows;          // [n] int64, sorted
  at::Tensor density;       // [n]
  at::Tensor sh;            // [n, K, 3]
  at::Tensor act_w, act_b;  // [R, 3] (zero without ACT)
};

// Live masks of density `dens` [M] at the grid coordinates `coords` [M, 3] (long) of the rows of `index`
// [X, Y, Z]: {cell_live [X, Y, Z], block_dist [BX, BY, BZ]} (uint8).
std::vector<at::Tensor> live(const at::Tensor& index, const at::Tensor& coords, const at::Tensor& dens,
                             int64_t shift);
Marched march_forward(const Rays& rays, const VoxelGrid& grid, const Field& field);
// fwd: march_forward's outputs; grads: their gradients. slots [B, M] int32, -1 on entry and on return: one row per
// OpenMP thread (B = the number of threads), where each thread finds the compact slot of a row (cell.h).
FieldGrads march_backward(const Rays& rays, const VoxelGrid& grid, const Field& field, const Marched& fwd,
                          const Marched& grads, const at::Tensor& slots);
// [M] the largest rendering weight of each stored point over the rays (pruning); field.sh is not read.
at::Tensor max_weights(const Rays& rays, const VoxelGrid& grid, const Field& field);

}  // namespace plx
