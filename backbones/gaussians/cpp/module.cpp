// Python bindings of the fused kernels (api.h; used by backbones/gaussians/fused.py). The argument structs are
// Python classes whose fields are set by name (an unknown name raises AttributeError). They are module-local, so two
// builds of the kernels (this tree's and another commit's, benchmarks/baseline.py) can be loaded in one process.
#include <torch/extension.h>

#include "api.h"

namespace py = pybind11;
using namespace arcsem;

#define FIELD(S, f) .def_readwrite(#f, &S::f)

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  py::class_<Raster>(m, "Raster", py::module_local()).def(py::init<>()) FIELD(Raster, C) FIELD(Raster, H) FIELD(Raster, W) FIELD(Raster, tile);
  py::class_<Projection>(m, "Projection", py::module_local())
      .def(py::init<>()) FIELD(Projection, means) FIELD(Projection, quats) FIELD(Projection, scales) FIELD(Projection, P)
          FIELD(Projection, view) FIELD(Projection, ortho) FIELD(Projection, near);
  py::class_<TileLists>(m, "TileLists", py::module_local())
      .def(py::init<>()) FIELD(TileLists, radii) FIELD(TileLists, visible) FIELD(TileLists, rects) FIELD(TileLists, box)
          FIELD(TileLists, offsets) FIELD(TileLists, ids) FIELD(TileLists, entry_offsets) FIELD(TileLists, pair_of);
  py::class_<ShColors>(m, "ShColors", py::module_local())
      .def(py::init<>()) FIELD(ShColors, means) FIELD(ShColors, sh_dc) FIELD(ShColors, sh_rest) FIELD(ShColors, origins)
          FIELD(ShColors, ortho) FIELD(ShColors, degree)
          FIELD(ShColors, act_w) FIELD(ShColors, act_b);
  py::class_<DensifyStatsIn>(m, "DensifyStatsIn", py::module_local())
      .def(py::init<>()) FIELD(DensifyStatsIn, grad_means) FIELD(DensifyStatsIn, means) FIELD(DensifyStatsIn, w2c)
          FIELD(DensifyStatsIn, K) FIELD(DensifyStatsIn, visible) FIELD(DensifyStatsIn, radii)
              FIELD(DensifyStatsIn, grad_sum) FIELD(DensifyStatsIn, count) FIELD(DensifyStatsIn, max_radii)
                  FIELD(DensifyStatsIn, ortho) FIELD(DensifyStatsIn, W) FIELD(DensifyStatsIn, H);
  py::class_<Splats3D>(m, "Splats3D", py::module_local())
      .def(py::init<>()) FIELD(Splats3D, means2d) FIELD(Splats3D, conics) FIELD(Splats3D, opacities)
          FIELD(Splats3D, colors) FIELD(Splats3D, depth) FIELD(Splats3D, background);
  py::class_<Composite3D>(m, "Composite3D", py::module_local())
      .def(py::init<>()) FIELD(Composite3D, rgb) FIELD(Composite3D, alpha) FIELD(Composite3D, depth)
          FIELD(Composite3D, pairs) FIELD(Composite3D, t_final) FIELD(Composite3D, wz) FIELD(Composite3D, last);
  py::class_<ColourWeights>(m, "ColourWeights", py::module_local())
      .def(py::init<>()) FIELD(ColourWeights, pix_ptr) FIELD(ColourWeights, pix_pair) FIELD(ColourWeights, pix_w)
          FIELD(ColourWeights, t_final) FIELD(ColourWeights, npairs);
  py::class_<Grads3D>(m, "Grads3D", py::module_local())
      .def(py::init<>()) FIELD(Grads3D, means2d) FIELD(Grads3D, conics) FIELD(Grads3D, opacities) FIELD(Grads3D, colors)
          FIELD(Grads3D, depth);
  py::class_<Surfels2D>(m, "Surfels2D", py::module_local())
      .def(py::init<>()) FIELD(Surfels2D, H) FIELD(Surfels2D, Dz) FIELD(Surfels2D, centres) FIELD(Surfels2D, opacities)
          FIELD(Surfels2D, colors) FIELD(Surfels2D, normals) FIELD(Surfels2D, mcoef) FIELD(Surfels2D, background)
              FIELD(Surfels2D, near) FIELD(Surfels2D, lowpass);
  py::class_<Composite2D>(m, "Composite2D", py::module_local())
      .def(py::init<>()) FIELD(Composite2D, rgb) FIELD(Composite2D, normal) FIELD(Composite2D, alpha)
          FIELD(Composite2D, depth) FIELD(Composite2D, median) FIELD(Composite2D, distortion) FIELD(Composite2D, pairs)
              FIELD(Composite2D, t_final) FIELD(Composite2D, wz) FIELD(Composite2D, m1) FIELD(Composite2D, m2)
                  FIELD(Composite2D, mref) FIELD(Composite2D, last) FIELD(Composite2D, median_pair);
  py::class_<Grads2D>(m, "Grads2D", py::module_local())
      .def(py::init<>()) FIELD(Grads2D, H) FIELD(Grads2D, Dz) FIELD(Grads2D, centres) FIELD(Grads2D, opacities)
          FIELD(Grads2D, colors) FIELD(Grads2D, normals);

  m.def("footprint_bin2d", &footprint_bin2d, "2DGS screen footprints and sorted tile lists (no gradient)",
        py::arg("Hm"), py::arg("Dz"), py::arg("opacities"), py::arg("raster"), py::arg("near"), py::arg("lowpass_sigma"));
  m.def("footprint_bin3d", &footprint_bin3d, "3DGS screen footprints and sorted tile lists (no gradient)",
        py::arg("means2d"), py::arg("depth"), py::arg("cov"), py::arg("opacities"), py::arg("raster"), py::arg("near"));
  m.def("project2d_forward", &project2d_forward, "2DGS homographies, centres, camera-facing normals", py::arg("p"));
  m.def("project2d_backward", &project2d_backward, "2DGS projection, backward", py::arg("p"), py::arg("g_H"),
        py::arg("g_Dz"), py::arg("g_centres"), py::arg("g_normals"));
  m.def("project3d_forward", &project3d_forward, "3DGS EWA projection and conics", py::arg("p"));
  m.def("project3d_backward", &project3d_backward, "3DGS projection, backward", py::arg("p"), py::arg("g_means2d"),
        py::arg("g_depth"), py::arg("g_conics"));
  m.def("densify_stats", &densify_stats, "one step's densification statistics, added in place", py::arg("a"));
  m.def("sh_colors_forward", &sh_colors_forward, "SH colours of every (camera, splat)", py::arg("a"));
  m.def("sh_colors_backward", &sh_colors_backward, "SH colours, backward", py::arg("a"), py::arg("g_colors"));
  m.def("composite3d_forward", &composite3d_forward, "3DGS tile compositing", py::arg("splats"), py::arg("lists"),
        py::arg("raster"));
  m.def("composite3d_backward", &composite3d_backward, "3DGS tile compositing, backward", py::arg("splats"),
        py::arg("lists"), py::arg("raster"), py::arg("fwd"), py::arg("g_rgb"), py::arg("g_alpha"), py::arg("g_depth"));
  m.def("composite2d_forward", &composite2d_forward, "2DGS tile compositing", py::arg("surfels"), py::arg("lists"),
        py::arg("raster"));
  m.def("composite2d_weights", &composite2d_weights, "2DGS compositing weights of a frozen geometry",
        py::arg("surfels"), py::arg("lists"), py::arg("raster"));
  m.def("composite3d_weights", &composite3d_weights, "3DGS compositing weights of a frozen geometry",
        py::arg("splats"), py::arg("lists"), py::arg("raster"));
  m.def("weights_backward", &weights_backward, "W^T g of a frozen geometry's compositing weights", py::arg("weights"),
        py::arg("raster"), py::arg("g"));
  m.def("composite2d_backward", &composite2d_backward, "2DGS tile compositing, backward", py::arg("surfels"),
        py::arg("lists"), py::arg("raster"), py::arg("fwd"), py::arg("g_rgb"), py::arg("g_normal"), py::arg("g_alpha"),
        py::arg("g_depth"), py::arg("g_median"), py::arg("g_distortion"), py::arg("geometry") = true);
}
