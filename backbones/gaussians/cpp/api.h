// Every kernel of the fused Gaussian rasteriser that Python calls (backbones/gaussians/fused.py), with its
// arguments named and grouped: module.cpp binds these declarations and the structs (their fields are set by
// name from Python), the .cpp files define them.
//
// Entries: the M = C * N (camera, splat) pairs of a render, s = c * N + n. Pairs: the P (tile, entry) pairs
// of the tile lists, sorted by camera-tile and by depth within a tile. Shapes are in the comments.
#pragma once
#include <torch/extension.h>

#include <vector>

namespace arcsem {

// The image grid: C cameras of H x W pixels in tiles of tile x tile pixels.
struct Raster {
  int64_t C = 1, H = 0, W = 0, tile = 16;
};

// Splat parameters to project (shared by 2DGS and 3DGS, forward and backward).
struct Projection {
  torch::Tensor means;   // [N, 3]
  torch::Tensor quats;   // [N, 4] (w, x, y, z), any norm
  torch::Tensor scales;  // [N, 2] (2DGS) or [N, 3] (3DGS)
  torch::Tensor P;       // [C, 4, 4] world -> (x w, y w, w, z) (raster_camera.pixel_projection)
  torch::Tensor view;    // [C, 3] camera forward (orthographic) or centre (pinhole); 2DGS normals only
  bool ortho = false;
  double near = 0.01;    // 3DGS: conics of centres at depth <= near are not inverted
};

// Footprints and tile lists (binning.cpp; no gradient). Entry s's pairs are pair_of[entry_offsets[s] ..
// entry_offsets[s + 1]): the kernels sum an entry's per-pair gradients in this fixed order, so results do not
// depend on the thread count or on timing.
struct TileLists {
  torch::Tensor radii;          // [M] int64, 0 where not visible
  torch::Tensor visible;        // [M] bool
  torch::Tensor rects;          // [M, 4] int64 tile rectangle (tx0, tx1, ty0, ty1), upper bounds exclusive
  torch::Tensor box;            // [M, 4] int64 inclusive pixel box (x0, x1, y0, y1) outside which alpha < 1/255
  torch::Tensor offsets;        // [C * TY * TX + 1] int64: tile t's pairs are [offsets[t], offsets[t + 1])
  torch::Tensor ids;            // [P] int64 entry of each pair
  torch::Tensor entry_offsets;  // [M + 1] int64
  torch::Tensor pair_of;        // [P] int64 pair positions grouped by entry
};

// 2DGS: Hm [M, 9] rows Tu, Tv, Tw; Dz [M, 3] row Tz; opacities [N]; lowpass_sigma in pixels.
TileLists footprint_bin2d(const torch::Tensor& Hm, const torch::Tensor& Dz, const torch::Tensor& opacities,
                          const Raster& raster, double near, double lowpass_sigma);
// 3DGS: means2d [M, 2], depth [M], cov (a, b, c) [M, 3], opacities [N].
TileLists footprint_bin3d(const torch::Tensor& means2d, const torch::Tensor& depth, const torch::Tensor& cov,
                          const torch::Tensor& opacities, const Raster& raster, double near);

// 2DGS projection -> {H [M, 9], Dz [M, 3], centres [M, 2], normals [M, 3]}.
std::vector<torch::Tensor> project2d_forward(const Projection& p);
// gradients of the four outputs -> {g_means [N, 3], g_quats [N, 4], g_scales [N, 2], g_shift [M, 2]}.
std::vector<torch::Tensor> project2d_backward(const Projection& p, const torch::Tensor& g_H, const torch::Tensor& g_Dz,
                                              const torch::Tensor& g_centres, const torch::Tensor& g_normals);
// 3DGS EWA projection -> {means2d [M, 2], depth [M], conics [M, 3], cov (a, b, c) [M, 3]}.
std::vector<torch::Tensor> project3d_forward(const Projection& p);
// -> {g_means [N, 3], g_quats [N, 4], g_scales [N, 3], g_shift [M, 2] (= g_means2d)}.
std::vector<torch::Tensor> project3d_backward(const Projection& p, const torch::Tensor& g_means2d,
                                              const torch::Tensor& g_depth, const torch::Tensor& g_conics);

// ---------------------------------------------------------------------------------------------- 3DGS compositing
struct Splats3D {
  torch::Tensor means2d;     // [M, 2] pixel centres
  torch::Tensor conics;      // [M, 3] (a, b, c): power = -0.5 (a dx^2 + c dy^2) - b dx dy
  torch::Tensor opacities;   // [M]
  torch::Tensor colors;      // [M, 3]
  torch::Tensor depth;       // [M] centre depth (composited into the depth map)
  torch::Tensor background;  // [3], or empty: none
};

struct Composite3D {
  torch::Tensor rgb, alpha, depth;  // [C, H, W, 3], [C, H, W, 1], [C, H, W, 1] (sum w z / alpha)
  // kept for the backward pass: the per-pair work list of the forward pass (bytes), final transmittance and
  // sum w z [C, H, W, 1], last composited pair [C, H, W] int32 (-1: none)
  torch::Tensor pairs, t_final, wz, last;
};

struct Grads3D {  // gradients of Splats3D's fields (means2d, conics, opacities, colors, depth)
  torch::Tensor means2d, conics, opacities, colors, depth;
};

Composite3D composite3d_forward(const Splats3D& s, const TileLists& lists, const Raster& raster);
// g_rgb, g_alpha, g_depth: gradients of the outputs; undefined or empty ones are zero
Grads3D composite3d_backward(const Splats3D& s, const TileLists& lists, const Raster& raster, const Composite3D& fwd,
                             const torch::Tensor& g_rgb, const torch::Tensor& g_alpha, const torch::Tensor& g_depth);

// ---------------------------------------------------------------------------------------------- 2DGS compositing
struct Surfels2D {
  torch::Tensor H;           // [M, 9] homography rows Tu, Tv, Tw
  torch::Tensor Dz;          // [M, 3] camera-z row Tz
  torch::Tensor centres;     // [M, 2] projected centres (the low-pass filter)
  torch::Tensor opacities;   // [M]
  torch::Tensor colors;      // [M, 3]
  torch::Tensor normals;     // [M, 3]
  torch::Tensor mcoef;       // [C, 3] normalised depth of the distortion term, m = m0 + m1 z + m2 / z
  torch::Tensor background;  // [3], or empty
  double near = 0.0;         // minimum hit depth
  double lowpass = 2.0;      // 1 / sigma^2 of the screen-space low-pass filter (pixels^-2)
};

struct Composite2D {
  torch::Tensor rgb, normal, alpha, depth, median, distortion;  // [C, H, W, 3 | 3 | 1 | 1 | 1 | 1]
  // kept for the backward pass: the per-pair work list, and per pixel T_final, sum w z, sum w m, sum w m^2, the
  // first splat's m (the shift of the distortion term) [C, H, W, 1], last and median pair [C, H, W] int32
  torch::Tensor pairs, t_final, wz, m1, m2, mref, last, median_pair;
};

struct Grads2D {  // gradients of Surfels2D's tensors (H, Dz, centres, opacities, colors, normals)
  torch::Tensor H, Dz, centres, opacities, colors, normals;
};

Composite2D composite2d_forward(const Surfels2D& s, const TileLists& lists, const Raster& raster);
Grads2D composite2d_backward(const Surfels2D& s, const TileLists& lists, const Raster& raster, const Composite2D& fwd,
                             const torch::Tensor& g_rgb, const torch::Tensor& g_normal, const torch::Tensor& g_alpha,
                             const torch::Tensor& g_depth, const torch::Tensor& g_median,
                             const torch::Tensor& g_distortion);

}  // namespace arcsem
