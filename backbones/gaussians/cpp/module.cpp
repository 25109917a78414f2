// Python bindings of the fused compositing kernels (see backbones/gaussians/fused.py).
#include <torch/extension.h>
#include <vector>

std::vector<torch::Tensor> forward3d(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                     torch::Tensor, torch::Tensor, int64_t, int64_t, int64_t, int64_t);
std::vector<torch::Tensor> backward3d(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                      torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                      int64_t, int64_t, int64_t, int64_t);

std::vector<torch::Tensor> forward2d(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                     torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, double, int64_t,
                                     int64_t, int64_t, int64_t);
std::vector<torch::Tensor> backward2d(torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                      torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, double, int64_t,
                                      int64_t, int64_t, int64_t, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                      torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor, torch::Tensor,
                                      torch::Tensor, torch::Tensor);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward3d", &forward3d, "3DGS tile compositing, forward");
  m.def("forward2d", &forward2d, "2DGS tile compositing, forward");
  m.def("backward2d", &backward2d, "2DGS tile compositing, backward");
  m.def("backward3d", &backward3d, "3DGS tile compositing, backward");
}
