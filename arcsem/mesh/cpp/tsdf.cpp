// One view fused into a TSDF volume in one pass over the voxels (arcsem/mesh/fused.py; the PyTorch reference is
// TSDFVolume._integrate_torch in arcsem/mesh/tsdf.py, the same arithmetic in float32 and the same rules):
//   camera point p_c = R p + t; pixel (u, v) = K (x/z, y/z) (orthographic: K (x, y)), floored;
//   d = table[v * W + u] (NaN: no observation, +inf: background clears the voxel, last entry: outside the view);
//   sdf = d - z; sdf >= -trunc: tsdf <- (tsdf w + clamp(sdf / trunc, -1, 1)) / (w + 1), w <- w + 1;
//   |sdf| < trunc and rgb given: colour <- (colour cw + rgb[pixel]) / (cw + 1), cw <- cw + 1.
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <cmath>
#include <cstdint>

namespace {

void check(const at::Tensor& t, const char* name, int64_t dim) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == at::kFloat && t.is_contiguous() && t.dim() == dim,
              name, ": a contiguous float32 CPU tensor of ", dim, " dimensions");
}

}  // namespace

// points [N, 3], w2c [3, 4], K [3, 3], table [H * W + 1], rgb [H * W, 3] or [0, 3]; tsdf, weight, color_weight [N]
// and color [N, 3] are updated in place.
void tsdf_integrate(const at::Tensor& points, const at::Tensor& w2c, const at::Tensor& K, bool ortho, int64_t width,
                    int64_t height, const at::Tensor& table, const at::Tensor& rgb, double trunc, at::Tensor tsdf,
                    at::Tensor weight, at::Tensor color, at::Tensor color_weight) {
  check(points, "points", 2);
  check(w2c, "w2c", 2);
  check(K, "K", 2);
  check(table, "table", 1);
  check(rgb, "rgb", 2);
  check(tsdf, "tsdf", 1);
  check(weight, "weight", 1);
  check(color, "color", 2);
  check(color_weight, "color_weight", 1);
  const int64_t n = points.size(0), hw = width * height;
  TORCH_CHECK(table.size(0) == hw + 1, "table: H * W + 1 entries");
  TORCH_CHECK(tsdf.size(0) == n && weight.size(0) == n && color.size(0) == n && color_weight.size(0) == n,
              "volume arrays: one entry per point");
  const bool with_rgb = rgb.size(0) > 0;
  TORCH_CHECK(!with_rgb || rgb.size(0) == hw, "rgb: H * W rows");
  const float* P = points.data_ptr<float>();
  const float* M = w2c.data_ptr<float>();
  const float* k = K.data_ptr<float>();
  const float* tab = table.data_ptr<float>();
  const float* col = with_rgb ? rgb.data_ptr<float>() : nullptr;
  float* T = tsdf.data_ptr<float>();
  float* Wt = weight.data_ptr<float>();
  float* C = color.data_ptr<float>();
  float* CW = color_weight.data_ptr<float>();
  const float fx = k[0], s = k[1], cx = k[2], fy = k[4], cy = k[5], tr = static_cast<float>(trunc);
  const float W = static_cast<float>(width), H = static_cast<float>(height);
  at::parallel_for(0, n, 1 << 14, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      const float px = P[3 * i], py = P[3 * i + 1], pz = P[3 * i + 2];
      const float xc = px * M[0] + py * M[1] + pz * M[2] + M[3];
      const float yc = px * M[4] + py * M[5] + pz * M[6] + M[7];
      const float z = px * M[8] + py * M[9] + pz * M[10] + M[11];
      if (!ortho && !(z > 0.f)) continue;  // behind a pinhole camera: not in the view
      const float x = ortho ? xc : xc / z, y = ortho ? yc : yc / z;
      float u = x * fx + cx;
      u += s * y;
      const float v = y * fy + cy;
      const float fu = std::floor(u), fv = std::floor(v);
      if (!(fu >= 0.f && fu < W && fv >= 0.f && fv < H)) continue;  // (NaN fails too)
      const int64_t pix = static_cast<int64_t>(fv) * width + static_cast<int64_t>(fu);
      const float sdf = tab[pix] - z;  // NaN: no observation; +inf: free space
      if (sdf >= -tr) {
        const float obs = std::fmin(std::fmax(sdf / tr, -1.f), 1.f);
        const float w = Wt[i];
        T[i] = (T[i] * w + obs) / (w + 1.f);
        Wt[i] = w + 1.f;
      }
      if (with_rgb && std::fabs(sdf) < tr) {
        const float cw = CW[i];
        for (int c = 0; c < 3; ++c) C[3 * i + c] = (C[3 * i + c] * cw + col[3 * pix + c]) / (cw + 1.f);
        CW[i] = cw + 1.f;
      }
    }
  });
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("tsdf_integrate", &tsdf_integrate, "fuse one view into a TSDF volume (in place)", py::arg("points"),
        py::arg("w2c"), py::arg("K"), py::arg("ortho"), py::arg("width"), py::arg("height"), py::arg("table"),
        py::arg("rgb"), py::arg("trunc"), py::arg("tsdf"), py::arg("weight"), py::arg("color"),
        py::arg("color_weight"));
}
