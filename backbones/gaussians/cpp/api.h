// Every kernel of the fused Gaussian rasteriser that Python calls (backbones/gaussians/fused.py), with its
// arguments named and grouped: module.cpp binds these declarations and the structs (their fields are set by
// name from Python), the .cpp files define them.
//
// Entries: the M = C * N (camera, splat) pairs of a render, s = c * N + n. Pairs: the P (tile, entry) pairs
// of the tile lists, sorted by camera-tile and by depth within a tile. Shapes are in the comments.
#pragma once
// ATen's tensor and the few factory functions the kernels use (not torch/extension.h: a kernel file then compiles
// in seconds instead of a minute; only module.cpp needs pybind11)
#include <ATen/Dispatch.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>
#include <ATen/ops/zeros.h>
#include <ATen/ops/zeros_like.h>

#include <vector>

namespace arcsem {

// The image grid: C cameras of H x W pixels in tiles of tile x tile pixels.
struct Raster {
  int64_t C = 1, H = 0, W = 0, tile = 16;
};

// Splat parameters to project (shared by 2DGS and 3DGS, forward and backward).
struct Projection {
  at::Tensor means;   // [N, 3]
  at::Tensor quats;   // [N, 4] (w, x, y, z), any norm
  at::Tensor scales;  // [N, 2] (2DGS) or [N, 3] (3DGS)
  at::Tensor P;       // [C, 4, 4] world -> (x w, y w, w, z) (raster_camera.pixel_projection)
  at::Tensor view;    // [C, 3] camera forward (orthographic) or centre (pinhole); 2DGS normals only
  bool ortho = false;
  double near = 0.01;    // 3DGS: conics of centres at depth <= near are not inverted
};

// Footprints and tile lists (binning.cpp; no gradient). Entry s's pairs are pair_of[entry_offsets[s] ..
// entry_offsets[s + 1]): the kernels sum an entry's per-pair gradients in this fixed order, so results do not
// depend on the thread count or on timing.
struct TileLists {
  at::Tensor radii;          // [M] int64, 0 where not visible
  at::Tensor visible;        // [M] bool
  at::Tensor rects;          // [M, 4] int64 tile rectangle (tx0, tx1, ty0, ty1), upper bounds exclusive
  at::Tensor box;            // [M, 4] int64 inclusive pixel box (x0, x1, y0, y1) outside which alpha < 1/255
  at::Tensor offsets;        // [C * TY * TX + 1] int64: tile t's pairs are [offsets[t], offsets[t + 1])
  at::Tensor ids;            // [P] int64 entry of each pair
  at::Tensor entry_offsets;  // [M + 1] int64
  at::Tensor pair_of;        // [P] int64 pair positions grouped by entry
};

// 2DGS: Hm [M, 9] rows Tu, Tv, Tw; Dz [M, 3] row Tz; opacities [N]; lowpass_sigma in pixels.
TileLists footprint_bin2d(const at::Tensor& Hm, const at::Tensor& Dz, const at::Tensor& opacities,
                          const Raster& raster, double near, double lowpass_sigma);
// 3DGS: means2d [M, 2], depth [M], cov (a, b, c) [M, 3], opacities [N].
TileLists footprint_bin3d(const at::Tensor& means2d, const at::Tensor& depth, const at::Tensor& cov,
                          const at::Tensor& opacities, const Raster& raster, double near);

// 2DGS projection -> {H [M, 9], Dz [M, 3], centres [M, 2], normals [M, 3]}.
std::vector<at::Tensor> project2d_forward(const Projection& p);
// gradients of the four outputs -> {g_means [N, 3], g_quats [N, 4], g_scales [N, 2], g_shift [M, 2]}.
std::vector<at::Tensor> project2d_backward(const Projection& p, const at::Tensor& g_H, const at::Tensor& g_Dz,
                                              const at::Tensor& g_centres, const at::Tensor& g_normals);
// 3DGS EWA projection -> {means2d [M, 2], depth [M], conics [M, 3], cov (a, b, c) [M, 3]}.
std::vector<at::Tensor> project3d_forward(const Projection& p);
// -> {g_means [N, 3], g_quats [N, 4], g_scales [N, 3], g_shift [M, 2] (= g_means2d)}.
std::vector<at::Tensor> project3d_backward(const Projection& p, const at::Tensor& g_means2d,
                                              const at::Tensor& g_depth, const at::Tensor& g_conics);

// ------------------------------------------------------------------------------ densification statistics (stats.cpp)
struct DensifyStatsIn {
  at::Tensor grad_means;  // [N, 3] dL/d mean
  at::Tensor means;       // [N, 3]
  at::Tensor w2c;         // [C, 4, 4] float64
  at::Tensor K;           // [C, 3, 3] float64
  at::Tensor visible;     // [C, N] bool
  at::Tensor radii;       // [C, N] long (pixels)
  at::Tensor grad_sum, count, max_radii;  // [N] float32 accumulators, updated in place
  bool ortho = false;
  int64_t W = 0, H = 0;
};

// adds one step's statistics to grad_sum, count, max_radii (densify.py: screen_grad_norms + DensifyStats.accumulate)
void densify_stats(const DensifyStatsIn& a);

// ---------------------------------------------------------------------------------------------- SH colours (sh.cpp)
struct ShColors {
  at::Tensor means;    // [N, 3]
  at::Tensor sh_dc;    // [N, 1, 3]
  at::Tensor sh_rest;  // [N, R, 3], R >= (degree + 1)^2 - 1
  at::Tensor origins;  // [C, 3] camera centres (pinhole) or forward axes (orthographic)
  bool ortho = false;
  int64_t degree = 0;     // 0..3
  at::Tensor act_w;       // [C, 3] per-camera affine colour transform (ACT) or empty: none
  at::Tensor act_b;       // [C, 3]
};

// -> [C, N, 3] rgb = max(SH(view direction) + 0.5, 0), with ACT clamp(act_w[c] rgb + act_b[c], 0, 1)
at::Tensor sh_colors_forward(const ShColors& a);
// -> {g_means [N, 3] (zero for orthographic cameras), g_sh_dc, g_sh_rest, g_act_w [C, 3], g_act_b [C, 3]} (the
// last two empty without ACT)
std::vector<at::Tensor> sh_colors_backward(const ShColors& a, const at::Tensor& g_colors);

// ---------------------------------------------------------------------------------------------- 3DGS compositing
struct Splats3D {
  at::Tensor means2d;     // [M, 2] pixel centres
  at::Tensor conics;      // [M, 3] (a, b, c): power = -0.5 (a dx^2 + c dy^2) - b dx dy
  at::Tensor opacities;   // [M]
  at::Tensor colors;      // [M, 3]
  at::Tensor depth;       // [M] centre depth (composited into the depth map)
  at::Tensor background;  // [3], or empty: none
};

// The weights w = alpha T a forward pass composited, of a frozen geometry: rgb = W colours[ids] + T_final bg.
struct ColourWeights {
  at::Tensor pix_ptr, pix_pair, pix_w;  // CSR over the C*H*W pixels (each row in depth order; int32 indices)
  at::Tensor t_final;                   // [C*H*W] final transmittance (the background's weight)
  int64_t npairs = 0;                   // pairs of the tile lists (the columns)
};

// W^T g: g [C*H*W, 3] per-pixel colour gradients -> [npairs, 3], the sum over each pair's pixels (every pair's
// pixels lie in its tile, so tiles add in parallel without races)
at::Tensor weights_backward(const ColourWeights& w, const Raster& raster, const at::Tensor& g);

struct Composite3D {
  at::Tensor rgb, alpha, depth;  // [C, H, W, 3], [C, H, W, 1], [C, H, W, 1] (sum w z / alpha)
  // kept for the backward pass: the per-pair work list of the forward pass (bytes), final transmittance and
  // sum w z [C, H, W, 1], last composited pair [C, H, W] int32 (-1: none)
  at::Tensor pairs, t_final, wz, last;
};

struct Grads3D {  // gradients of Splats3D's fields (means2d, conics, opacities, colors, depth)
  at::Tensor means2d, conics, opacities, colors, depth;
};

Composite3D composite3d_forward(const Splats3D& s, const TileLists& lists, const Raster& raster);
// the compositing weights of the forward pass (weights.h): pixel-major CSR pix_ptr [C*H*W + 1], pix_pair (pair
// positions in lists.ids), pix_w
ColourWeights composite3d_weights(const Splats3D& s, const TileLists& lists, const Raster& raster);
// g_rgb, g_alpha, g_depth: gradients of the outputs; undefined or empty ones are zero
Grads3D composite3d_backward(const Splats3D& s, const TileLists& lists, const Raster& raster, const Composite3D& fwd,
                             const at::Tensor& g_rgb, const at::Tensor& g_alpha, const at::Tensor& g_depth);

// ---------------------------------------------------------------------------------------------- 2DGS compositing
struct Surfels2D {
  at::Tensor H;           // [M, 9] homography rows Tu, Tv, Tw
  at::Tensor Dz;          // [M, 3] camera-z row Tz
  at::Tensor centres;     // [M, 2] projected centres (the low-pass filter)
  at::Tensor opacities;   // [M]
  at::Tensor colors;      // [M, 3]
  at::Tensor normals;     // [M, 3]
  at::Tensor mcoef;       // [C, 3] normalised depth of the distortion term, m = m0 + m1 z + m2 / z
  at::Tensor background;  // [3], or empty
  double near = 0.0;         // minimum hit depth
  double lowpass = 2.0;      // 1 / sigma^2 of the screen-space low-pass filter (pixels^-2)
};

struct Composite2D {
  at::Tensor rgb, normal, alpha, depth, median, distortion;  // [C, H, W, 3 | 3 | 1 | 1 | 1 | 1]
  // kept for the backward pass: the per-pair work list, and per pixel T_final, sum w z, sum w m, sum w m^2, the
  // first splat's m (the shift of the distortion term) [C, H, W, 1], last and median pair [C, H, W] int32
  at::Tensor pairs, t_final, wz, m1, m2, mref, last, median_pair;
};

struct Grads2D {  // gradients of Surfels2D's tensors (H, Dz, centres, opacities, colors, normals)
  at::Tensor H, Dz, centres, opacities, colors, normals;
};

Composite2D composite2d_forward(const Surfels2D& s, const TileLists& lists, const Raster& raster);
ColourWeights composite2d_weights(const Surfels2D& s, const TileLists& lists, const Raster& raster);
// geometry = false: only the colour gradient (the others undefined), for frozen geometry (stage 2)
Grads2D composite2d_backward(const Surfels2D& s, const TileLists& lists, const Raster& raster, const Composite2D& fwd,
                             const at::Tensor& g_rgb, const at::Tensor& g_normal, const at::Tensor& g_alpha,
                             const at::Tensor& g_depth, const at::Tensor& g_median,
                             const at::Tensor& g_distortion, bool geometry = true);

}  // namespace arcsem
