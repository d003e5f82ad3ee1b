// pybind11 glue: numpy buffers in, numpy buffers out; no torch here (the build must not need
// it). Shapes are re-checked so a wrong call raises ValueError instead of reading past a buffer.
#include <omp.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <array>
#include <initializer_list>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "projection.h"
#include "rasterize.h"

namespace py = pybind11;
using namespace splat;

namespace {

template <typename T>
using Arr = py::array_t<T, py::array::c_style | py::array::forcecast>;

template <typename T>
void check(const Arr<T>& a, const char* name, std::initializer_list<int64_t> shape) {
  bool ok = a.ndim() == (py::ssize_t)shape.size();
  int i = 0;
  for (int64_t d : shape) {
    if (ok && d >= 0 && a.shape(i) != d) ok = false;
    ++i;
  }
  if (!ok) {
    std::string seen = "(";
    for (py::ssize_t j = 0; j < a.ndim(); ++j) seen += (j ? "," : "") + std::to_string(a.shape(j));
    throw py::value_error(std::string("native splat: bad shape for ") + name + ": " + seen + ")");
  }
}

template <typename T>
Arr<T> empty(std::vector<py::ssize_t> shape) {
  return Arr<T>(shape);
}

template <typename T>
py::array_t<T> from_vector(std::vector<T>&& v) {
  auto* heap = new std::vector<T>(std::move(v));
  py::capsule owner(heap, [](void* p) { delete reinterpret_cast<std::vector<T>*>(p); });
  return py::array_t<T>({(py::ssize_t)heap->size()}, {(py::ssize_t)sizeof(T)}, heap->data(), owner);
}

// means (N,3), quats (N,4), log_scales (N,3) -> N
int64_t check_gaussians(const Arr<float>& means, const Arr<float>& quats,
                        const Arr<float>& log_scales) {
  const int64_t n = means.ndim() == 2 ? means.shape(0) : -1;
  check(means, "means", {n, 3});
  check(quats, "quats", {n, 4});
  check(log_scales, "log_scales", {n, 3});
  return n;
}

Camera make_camera(const Arr<float>& viewmat, float fx, float fy, float cx, float cy, int width,
                   int height, float near_plane, const std::array<int, 4>& window,
                   float beside) {
  check(viewmat, "viewmat", {4, 4});
  if (width < 1 || height < 1) throw py::value_error("native splat: width and height must be >= 1");
  const auto [x0, y0, fw, fh] = window;
  if (x0 < 0 || y0 < 0 || x0 + width > fw || y0 + height > fh)
    throw py::value_error("native splat: the window is not inside its full view");
  Camera cam;
  for (int i = 0; i < 16; ++i) cam.viewmat[i] = viewmat.data()[i];
  cam.fx = fx;
  cam.fy = fy;
  cam.cx = cx;
  cam.cy = cy;
  cam.width = width;
  cam.height = height;
  cam.near_plane = near_plane;
  cam.win_x0 = x0;
  cam.win_y0 = y0;
  cam.full_width = fw;
  cam.full_height = fh;
  cam.beside = beside;
  return cam;
}

// sh (N,K,C) or None -> the ShInput the kernels take (checked against n and degree).
ShInput sh_input(const std::optional<Arr<float>>& sh, int64_t n, int degree) {
  ShInput in;
  if (!sh) return in;
  if (degree < 0 || degree > 3) throw py::value_error("native splat: sh degree must be 0..3");
  check(*sh, "sh", {n, -1, -1});
  if (sh->shape(1) < (degree + 1) * (degree + 1))
    throw py::value_error("native splat: sh has too few coefficients for its degree");
  in.sh = sh->data();
  in.K = (int)sh->shape(1);
  in.C = (int)sh->shape(2);
  in.degree = degree;
  return in;
}

py::tuple project_fwd(Arr<float> means, Arr<float> quats, Arr<float> log_scales,
                      Arr<float> opacities, Arr<float> viewmat, float fx, float fy, float cx,
                      float cy, int width, int height, float near_plane,
                      std::array<int, 4> window, float beside, std::optional<Arr<float>> sh,
                      int degree, int threads) {
  const int64_t n = check_gaussians(means, quats, log_scales);
  check(opacities, "opacities", {n});
  const Camera cam = make_camera(viewmat, fx, fy, cx, cy, width, height, near_plane, window, beside);
  const ShInput shi = sh_input(sh, n, degree);
  auto means2d = empty<float>({n, 2});
  auto conics = empty<float>({n, 3});
  auto depths = empty<float>({n});
  auto radii = empty<int32_t>({n});
  auto colors = empty<float>({n, shi.C});
  {
    py::gil_scoped_release nogil;
    project_forward(n, means.data(), quats.data(), log_scales.data(), opacities.data(), cam, shi,
                    means2d.mutable_data(), conics.mutable_data(), depths.mutable_data(),
                    radii.mutable_data(), colors.mutable_data(), threads);
  }
  return py::make_tuple(means2d, conics, depths, radii, sh ? py::object(colors) : py::none());
}

py::tuple project_bwd(Arr<float> means, Arr<float> quats, Arr<float> log_scales,
                      Arr<int32_t> radii, Arr<float> viewmat, float fx, float fy, float cx,
                      float cy, int width, int height, float near_plane,
                      std::array<int, 4> window, float beside, Arr<float> v_means2d,
                      Arr<float> v_conics, Arr<float> v_depths, std::optional<Arr<float>> sh,
                      std::optional<Arr<float>> colors, std::optional<Arr<float>> v_colors,
                      int degree, int threads) {
  const int64_t n = check_gaussians(means, quats, log_scales);
  check(radii, "radii", {n});
  check(v_means2d, "v_means2d", {n, 2});
  check(v_conics, "v_conics", {n, 3});
  check(v_depths, "v_depths", {n});
  const Camera cam = make_camera(viewmat, fx, fy, cx, cy, width, height, near_plane, window, beside);
  const ShInput shi = sh_input(sh, n, degree);
  if (sh) {
    if (!colors || !v_colors) throw py::value_error("native splat: sh needs colors and v_colors");
    check(*colors, "colors", {n, shi.C});
    check(*v_colors, "v_colors", {n, shi.C});
  }
  auto v_means = empty<float>({n, 3});
  auto v_quats = empty<float>({n, 4});
  auto v_scales = empty<float>({n, 3});
  auto v_view = empty<float>({4, 4});
  auto v_sh = empty<float>({sh ? n : 0, shi.K, shi.C});
  {
    py::gil_scoped_release nogil;
    project_backward(n, means.data(), quats.data(), log_scales.data(), radii.data(), cam, shi,
                     sh ? colors->data() : nullptr, v_means2d.data(), v_conics.data(),
                     v_depths.data(), sh ? v_colors->data() : nullptr, v_means.mutable_data(),
                     v_quats.mutable_data(), v_scales.mutable_data(), v_view.mutable_data(),
                     v_sh.mutable_data(), threads);
  }
  return py::make_tuple(v_means, v_quats, v_scales, v_view, sh ? py::object(v_sh) : py::none());
}

RasterScene make_scene(const Arr<float>& means2d, const Arr<float>& conics,
                       const Arr<float>& colors, const Arr<float>& opacities,
                       const Arr<float>& depths, const Arr<int32_t>& radii, int width,
                       int height) {
  const int64_t n = means2d.ndim() == 2 ? means2d.shape(0) : -1;
  check(means2d, "means2d", {n, 2});
  check(conics, "conics", {n, 3});
  check(colors, "colors", {n, -1});
  check(opacities, "opacities", {n});
  check(depths, "depths", {n});
  check(radii, "radii", {n});
  if (colors.shape(1) < 1) throw py::value_error("native splat: colors need >= 1 channel");
  if (width < 1 || height < 1) throw py::value_error("native splat: width and height must be >= 1");
  if (n > 2147483647LL) throw py::value_error("native splat: too many Gaussians for int32 ids");
  return {n, (int)colors.shape(1), width, height, means2d.data(), conics.data(),
          colors.data(), opacities.data(), depths.data(), radii.data()};
}

py::tuple raster_fwd(Arr<float> means2d, Arr<float> conics, Arr<float> colors,
                     Arr<float> opacities, Arr<float> depths, Arr<int32_t> radii, int width,
                     int height, int64_t max_pairs, int threads) {
  const RasterScene s = make_scene(means2d, conics, colors, opacities, depths, radii, width, height);
  auto image = empty<float>({height, width, s.channels});
  auto alpha = empty<float>({height, width});
  auto depth = empty<float>({height, width});
  auto final_T = empty<float>({height, width});
  auto last = empty<int32_t>({height, width});
  Binning bins;
  double bin_seconds;
  {
    py::gil_scoped_release nogil;
    const double t0 = omp_get_wtime();
    bin_gaussians(s, max_pairs, threads, bins);
    bin_seconds = omp_get_wtime() - t0;
    rasterize_forward(s, view_of(bins), image.mutable_data(), alpha.mutable_data(),
                      depth.mutable_data(), final_T.mutable_data(), last.mutable_data(), threads);
  }
  const int tx = bins.tiles_x, ty = bins.tiles_y;
  return py::make_tuple(image, alpha, depth, final_T, last, tx, ty,
                        from_vector(std::move(bins.offsets)), from_vector(std::move(bins.ids)),
                        from_vector(std::move(bins.boxes)), bin_seconds);
}

py::tuple raster_bwd(Arr<float> means2d, Arr<float> conics, Arr<float> colors,
                     Arr<float> opacities, Arr<float> depths, Arr<int32_t> radii, int width,
                     int height, Arr<float> final_T, Arr<int32_t> last, int tiles_x,
                     int tiles_y, Arr<int64_t> offsets, Arr<int32_t> ids, Arr<int32_t> boxes,
                     Arr<float> v_image, Arr<float> v_alpha, Arr<float> v_depth, int threads) {
  const RasterScene s = make_scene(means2d, conics, colors, opacities, depths, radii, width, height);
  check(final_T, "final_T", {height, width});
  check(last, "last", {height, width});
  check(v_image, "v_image", {height, width, s.channels});
  check(v_alpha, "v_alpha", {height, width});
  check(v_depth, "v_depth", {height, width});
  const int64_t n_tiles = (int64_t)tiles_x * tiles_y;
  check(offsets, "offsets", {n_tiles + 1});
  check(ids, "ids", {-1});
  check(boxes, "boxes", {4 * s.n});
  auto v_means2d = empty<float>({s.n, 2});
  auto v_conics = empty<float>({s.n, 3});
  auto v_colors = empty<float>({s.n, s.channels});
  auto v_opac = empty<float>({s.n});
  auto v_depths = empty<float>({s.n});
  const BinView bins{tiles_x, tiles_y, offsets.data(), ids.data(), boxes.data()};
  {
    py::gil_scoped_release nogil;
    rasterize_backward(s, bins, final_T.data(), last.data(), v_image.data(), v_alpha.data(),
                       v_depth.data(), v_means2d.mutable_data(), v_conics.mutable_data(),
                       v_colors.mutable_data(), v_opac.mutable_data(), v_depths.mutable_data(),
                       threads);
  }
  return py::make_tuple(v_means2d, v_conics, v_colors, v_opac, v_depths);
}

}  // namespace

PYBIND11_MODULE(_native, m) {
  m.doc() = "Native CPU kernels of recon.splat (projection with SH colour, tile rasterizer); use recon.splat.";
  m.def("project_forward", &project_fwd);
  m.def("project_backward", &project_bwd);
  m.def("rasterize_forward", &raster_fwd);
  m.def("rasterize_backward", &raster_bwd);
  py::register_exception<std::length_error>(m, "TooManyIntersections", PyExc_MemoryError);
}
