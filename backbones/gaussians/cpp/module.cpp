// Python bindings of the fused compositing kernels (see backbones/gaussians/fused.py).
#include <torch/extension.h>
#include <vector>

using T_ = torch::Tensor;
std::vector<T_> forward3d(T_, T_, T_, T_, T_, T_, T_, T_, T_, int64_t, int64_t, int64_t, int64_t);
std::vector<T_> backward3d(T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, int64_t, int64_t, int64_t, int64_t);
std::vector<T_> forward2d(T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, double, double, int64_t, int64_t, int64_t, int64_t);
std::vector<T_> backward2d(T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, double, double, int64_t, int64_t, int64_t, int64_t, T_, T_,
                           T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_, T_);
std::vector<torch::Tensor> footprint_bin2d(torch::Tensor, torch::Tensor, torch::Tensor, int64_t, double, int64_t, int64_t, int64_t,
                                           double);
std::vector<torch::Tensor> footprint_bin3d(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, int64_t, double,
                                           int64_t, int64_t, int64_t);
std::vector<torch::Tensor> project2d_forward(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                             bool);
std::vector<torch::Tensor> project2d_backward(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                              bool, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor);
std::vector<torch::Tensor> project3d_forward(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, double);
std::vector<torch::Tensor> project3d_backward(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, double,
                                              torch::Tensor, torch::Tensor, torch::Tensor);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward3d", &forward3d, "3DGS tile compositing, forward");
  m.def("forward2d", &forward2d, "2DGS tile compositing, forward");
  m.def("backward2d", &backward2d, "2DGS tile compositing, backward");
  m.def("backward3d", &backward3d, "3DGS tile compositing, backward");
  m.def("footprint_bin2d", &footprint_bin2d, "2DGS screen footprints and sorted tile pairs (no gradient)");
  m.def("footprint_bin3d", &footprint_bin3d, "3DGS screen footprints and sorted tile pairs (no gradient)");
  m.def("project2d_forward", &project2d_forward, "2DGS homographies, centres, camera-facing normals");
  m.def("project2d_backward", &project2d_backward, "2DGS projection, backward");
  m.def("project3d_forward", &project3d_forward, "3DGS EWA projection and conics");
  m.def("project3d_backward", &project3d_backward, "3DGS projection, backward");
}
