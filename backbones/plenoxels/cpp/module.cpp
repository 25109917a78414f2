// Python bindings of the fused Plenoxels marcher (api.h; used by backbones/plenoxels/fused.py). The argument structs
// are Python classes whose fields are set by name (an unknown name raises AttributeError); module-local, so another
// build of the marcher (benchmarks/bench_plenoxels_marcher.py) can be loaded in the same process.
#include <torch/extension.h>

#include "api.h"

namespace py = pybind11;
using namespace plx;

#define FIELD(S, f) .def_readwrite(#f, &S::f)

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  py::class_<VoxelGrid>(m, "VoxelGrid", py::module_local())
      .def(py::init<>()) FIELD(VoxelGrid, index) FIELD(VoxelGrid, cell_live) FIELD(VoxelGrid, block_dist)
          FIELD(VoxelGrid, bounds) FIELD(VoxelGrid, shift);
  py::class_<Field>(m, "Field", py::module_local())
      .def(py::init<>()) FIELD(Field, density) FIELD(Field, sh) FIELD(Field, degree) FIELD(Field, act)
          FIELD(Field, act_w) FIELD(Field, act_b);
  py::class_<Rays>(m, "Rays", py::module_local())
      .def(py::init<>()) FIELD(Rays, origins) FIELD(Rays, directions) FIELD(Rays, step) FIELD(Rays, scale)
          FIELD(Rays, stop);
  py::class_<Marched>(m, "Marched", py::module_local())
      .def(py::init<>()) FIELD(Marched, rgb) FIELD(Marched, alpha) FIELD(Marched, wt) FIELD(Marched, mom);
  py::class_<FieldGrads>(m, "FieldGrads", py::module_local())
      .def(py::init<>()) FIELD(FieldGrads, rows) FIELD(FieldGrads, density) FIELD(FieldGrads, sh)
          FIELD(FieldGrads, act_w) FIELD(FieldGrads, act_b);

  m.def("live", &live, "Plenoxels live cells and block distances of a density", py::arg("index"), py::arg("coords"),
        py::arg("dens"), py::arg("shift"));
  m.def("forward", &march_forward, "Plenoxels fused ray marching (forward)", py::arg("rays"), py::arg("grid"),
        py::arg("field"));
  m.def("backward", &march_backward, "Plenoxels fused ray marching (backward)", py::arg("rays"), py::arg("grid"),
        py::arg("field"), py::arg("fwd"), py::arg("grads"), py::arg("slots"));
  m.def("max_weights", &max_weights, "Plenoxels largest rendering weight per stored point (pruning)",
        py::arg("rays"), py::arg("grid"), py::arg("field"));
}
