// Python bindings of the fused loss kernels (used by losses/fused.py).
#include <torch/extension.h>

#include <vector>

std::vector<at::Tensor> ssim_forward(const at::Tensor& x, const at::Tensor& y, const at::Tensor& g);
at::Tensor ssim_backward(const at::Tensor& g_map, const at::Tensor& x, const at::Tensor& y, const at::Tensor& g,
                         const at::Tensor& stats);
std::vector<at::Tensor> normal_consistency_forward(const at::Tensor& depth, const at::Tensor& o, const at::Tensor& d,
                                                   const at::Tensor& normal, const at::Tensor& alpha);
std::vector<at::Tensor> normal_consistency_backward(double g, double count, const at::Tensor& depth,
                                                    const at::Tensor& o,
                                                    const at::Tensor& d, const at::Tensor& normal,
                                                    const at::Tensor& alpha);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("ssim_forward", &ssim_forward, "SSIM map and the five blurred statistics", py::arg("x"), py::arg("y"),
        py::arg("window"));
  m.def("ssim_backward", &ssim_backward, "gradient of the SSIM map with respect to x", py::arg("g_map"), py::arg("x"),
        py::arg("y"), py::arg("window"), py::arg("stats"));
  m.def("normal_consistency_forward", &normal_consistency_forward, "2DGS normal consistency (official form)",
        py::arg("depth"), py::arg("origins"), py::arg("dirs"), py::arg("normal"), py::arg("alpha"));
  m.def("normal_consistency_backward", &normal_consistency_backward, "its gradients of depth and normal",
        py::arg("g"), py::arg("count"), py::arg("depth"), py::arg("origins"), py::arg("dirs"), py::arg("normal"),
        py::arg("alpha"));
}
