// SSIM's training loss and its separable, zero-padded blur, natively, on channels-last images.
// Through torch, the loss at 640x480 was ~17 ms forward + backward: two depthwise conv2d blurs
// (6-7 ms per 1-D pass of 15 channels) and ~40 image-sized elementwise ops. Here each output row
// is one vertical sum of 2r+1 input rows and one horizontal sum within it, over contiguous runs of
// W*C floats that the compiler vectorises, and the SSIM arithmetic is done on that row in cache.
// The form is fused-ssim's (Mallick et al.): the blur G is self-adjoint, so with S the SSIM map
// dS/da = G(dS/dmu_a) + 2a G(dS/ds_aa) + b G(dS/ds_ab); the forward stores the three (four with
// b's) per-pixel partials and the backward blurs them.
#include <omp.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace py = pybind11;

namespace {

constexpr float kC1 = 0.01f * 0.01f, kC2 = 0.03f * 0.03f;

// Row y of `planes` planes of one image, each (H, row) floats, blurred into out[p] (row floats
// each). tmp: planes x (row + 2 pad) floats of scratch whose pad floats either side stay 0 (the
// horizontal zero padding). in(yy, g, t, stride) adds g x input row yy of plane p to
// t + p * stride, for every plane: the vertical pass, so inputs can be computed on the fly.
template <typename In>
void blur_row(int planes, int64_t H, int64_t y, int64_t row, int64_t K, const float* taps, int r,
              float* tmp, float* const* out, In in) {
  const int64_t pad = (int64_t)r * K, stride = row + 2 * pad;
  for (int p = 0; p < planes; ++p) std::fill(tmp + p * stride + pad, tmp + p * stride + pad + row, 0.f);
  for (int i = -r; i <= r; ++i) {
    if (y + i < 0 || y + i >= H) continue;
    in(y + i, taps[i + r], tmp + pad, stride);
  }
  for (int p = 0; p < planes; ++p) {
    float* dst = out[p];
    const float* t = tmp + p * stride + pad;
    std::fill(dst, dst + row, 0.f);
    for (int j = -r; j <= r; ++j) {
      const float g = taps[j + r];
      const float* src = t + (int64_t)j * K;
#pragma omp simd
      for (int64_t e = 0; e < row; ++e) dst[e] += g * src[e];
    }
  }
}

struct Image {
  int64_t B, H, W, K;
  int64_t row() const { return W * K; }
  int64_t plane() const { return B * H * W * K; }
};

// x, out: (B, H, W, K). out = G x per channel, zero padding (conv2d's, vertical first).
void blur(const float* x, float* out, const Image& im, const float* taps, int r, int threads) {
  const int64_t row = im.row(), pad = (int64_t)r * im.K;
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<float> tmp(row + 2 * pad, 0.f);
#pragma omp for schedule(static)
    for (int64_t by = 0; by < im.B * im.H; ++by) {
      const int64_t b = by / im.H, y = by % im.H;
      float* dst = out + by * row;
      blur_row(1, im.H, y, row, im.K, taps, r, tmp.data(), &dst,
               [&](int64_t yy, float g, float* t, int64_t) {
                 const float* src = x + (b * im.H + yy) * row;
#pragma omp simd
                 for (int64_t e = 0; e < row; ++e) t[e] += g * src[e];
               });
    }
  }
}

// a, b: (B, H, W, C) -> sum of the SSIM map (double, summed per row then in row order: the same
// bits for any thread count), and partials (4, B, H, W, C): dS/dmu_a, dS/dmu_b, dS/ds_aa
// (= dS/ds_bb), dS/ds_ab at each pixel.
double ssim_forward(const float* a, const float* b, float* partials, const Image& im, const float* taps,
                    int r, int threads) {
  const int64_t row = im.row(), pad = (int64_t)r * im.K, rows = im.B * im.H, plane = im.plane();
  std::vector<double> row_sum(rows);
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<float> tmp(5 * (row + 2 * pad), 0.f), stats(5 * row);
#pragma omp for schedule(static)
    for (int64_t by = 0; by < rows; ++by) {
      const int64_t b0 = by / im.H, y = by % im.H;
      float* st[5];
      for (int p = 0; p < 5; ++p) st[p] = stats.data() + p * row;
      blur_row(5, im.H, y, row, im.K, taps, r, tmp.data(), st,
               [&](int64_t yy, float g, float* t, int64_t stride) {
                 const float* pa = a + (b0 * im.H + yy) * row;
                 const float* pb = b + (b0 * im.H + yy) * row;
                 float *t0 = t, *t1 = t + stride, *t2 = t + 2 * stride, *t3 = t + 3 * stride, *t4 = t + 4 * stride;
#pragma omp simd
                 for (int64_t e = 0; e < row; ++e) {
                   const float va = pa[e], vb = pb[e];
                   t0[e] += g * va;
                   t1[e] += g * vb;
                   t2[e] += g * (va * va);
                   t3[e] += g * (vb * vb);
                   t4[e] += g * (va * vb);
                 }
               });
      float* d_mua = partials + by * row;
      float* d_mub = d_mua + plane;
      float* d_sq = d_mua + 2 * plane;
      float* d_ab = d_mua + 3 * plane;
      double sum = 0.0;
#pragma omp simd reduction(+ : sum)
      for (int64_t e = 0; e < row; ++e) {
        const float mu_a = st[0][e], mu_b = st[1][e];
        const float mu_ab = mu_a * mu_b, mu_aa = mu_a * mu_a, mu_bb = mu_b * mu_b;
        const float a1 = 2 * mu_ab + kC1, a2 = 2 * (st[4][e] - mu_ab) + kC2;
        const float b1 = mu_aa + mu_bb + kC1, b2 = (st[2][e] - mu_aa) + (st[3][e] - mu_bb) + kC2;
        const float den = b1 * b2, s = (a1 * a2) / den;
        const float k = (a2 - a1) / den, t = s * (1 / b1 - 1 / b2);
        d_mua[e] = 2 * (mu_b * k - mu_a * t);
        d_mub[e] = 2 * (mu_a * k - mu_b * t);
        d_sq[e] = -s / b2;
        d_ab[e] = 2 * a1 / den;
        sum += s;
      }
      row_sum[by] = sum;
    }
  }
  double total = 0.0;
  for (double s : row_sum) total += s;
  return total;
}

// grad_a = scale (G d_mua + 2a G d_sq + b G d_ab), grad_b likewise with d_mub (either may be null).
void ssim_backward(const float* a, const float* b, const float* partials, float scale, float* grad_a,
                   float* grad_b, const Image& im, const float* taps, int r, int threads) {
  const int64_t row = im.row(), pad = (int64_t)r * im.K, rows = im.B * im.H, plane = im.plane();
  // blurred planes: d_mua if grad_a, d_mub if grad_b, then d_sq, d_ab
  std::vector<int> which;
  if (grad_a) which.push_back(0);
  if (grad_b) which.push_back(1);
  which.push_back(2);
  which.push_back(3);
  const int np = (int)which.size();
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<float> tmp(np * (row + 2 * pad), 0.f), blurred(np * row);
#pragma omp for schedule(static)
    for (int64_t by = 0; by < rows; ++by) {
      const int64_t b0 = by / im.H, y = by % im.H;
      float* bl[4];
      for (int p = 0; p < np; ++p) bl[p] = blurred.data() + p * row;
      blur_row(np, im.H, y, row, im.K, taps, r, tmp.data(), bl,
               [&](int64_t yy, float g, float* t, int64_t stride) {
                 for (int p = 0; p < np; ++p) {
                   const float* src = partials + which[p] * plane + (b0 * im.H + yy) * row;
                   float* tp = t + p * stride;
#pragma omp simd
                   for (int64_t e = 0; e < row; ++e) tp[e] += g * src[e];
                 }
               });
      const float* g_sq = bl[np - 2];
      const float* g_ab = bl[np - 1];
      const float* pa = a + by * row;
      const float* pb = b + by * row;
      if (grad_a) {
        float* ga = grad_a + by * row;
        const float* g_mu = bl[0];
#pragma omp simd
        for (int64_t e = 0; e < row; ++e) ga[e] = scale * (g_mu[e] + 2 * pa[e] * g_sq[e] + pb[e] * g_ab[e]);
      }
      if (grad_b) {
        float* gb = grad_b + by * row;
        const float* g_mu = bl[grad_a ? 1 : 0];
#pragma omp simd
        for (int64_t e = 0; e < row; ++e) gb[e] = scale * (g_mu[e] + 2 * pb[e] * g_sq[e] + pa[e] * g_ab[e]);
      }
    }
  }
}

using Arr = py::array_t<float, py::array::c_style | py::array::forcecast>;

Image image_of(const Arr& x, const char* name) {
  if (x.ndim() != 4)
    throw py::value_error(std::string("native ssim: ") + name + " must be (B, H, W, C), got ndim " +
                          std::to_string(x.ndim()));
  return {x.shape(0), x.shape(1), x.shape(2), x.shape(3)};
}

void same_shape(const Arr& x, const Image& im, const char* name) {
  const Image other = image_of(x, name);
  if (other.B != im.B || other.H != im.H || other.W != im.W || other.K != im.K)
    throw py::value_error(std::string("native ssim: ") + name + " differs in shape from a");
}

int radius(const Arr& taps) {
  if (taps.ndim() != 1 || taps.shape(0) % 2 != 1)
    throw py::value_error("native ssim: taps must be 1-D of odd length");
  return (int)taps.shape(0) / 2;
}

Arr blur_py(Arr x, Arr taps, int threads) {
  const Image im = image_of(x, "x");
  const int r = radius(taps);
  Arr out({im.B, im.H, im.W, im.K});
  {
    py::gil_scoped_release nogil;
    blur(x.data(), out.mutable_data(), im, taps.data(), r, threads);
  }
  return out;
}

py::tuple ssim_forward_py(Arr a, Arr b, Arr taps, int threads) {
  const Image im = image_of(a, "a");
  same_shape(b, im, "b");
  const int r = radius(taps);
  Arr partials({(int64_t)4, im.B, im.H, im.W, im.K});
  double total;
  {
    py::gil_scoped_release nogil;
    total = ssim_forward(a.data(), b.data(), partials.mutable_data(), im, taps.data(), r, threads);
  }
  return py::make_tuple(total, partials);
}

py::tuple ssim_backward_py(Arr a, Arr b, Arr partials, Arr taps, float scale, bool need_a, bool need_b,
                           int threads) {
  const Image im = image_of(a, "a");
  same_shape(b, im, "b");
  if (partials.ndim() != 5 || partials.shape(0) != 4 || partials.size() != 4 * im.plane())
    throw py::value_error("native ssim: partials must be (4, B, H, W, C) of a's shape");
  const int r = radius(taps);
  py::object ga = py::none(), gb = py::none();
  Arr grad_a, grad_b;
  if (need_a) grad_a = Arr({im.B, im.H, im.W, im.K});
  if (need_b) grad_b = Arr({im.B, im.H, im.W, im.K});
  {
    py::gil_scoped_release nogil;
    ssim_backward(a.data(), b.data(), partials.data(), scale, need_a ? grad_a.mutable_data() : nullptr,
                  need_b ? grad_b.mutable_data() : nullptr, im, taps.data(), r, threads);
  }
  if (need_a) ga = grad_a;
  if (need_b) gb = grad_b;
  return py::make_tuple(ga, gb);
}

}  // namespace

PYBIND11_MODULE(_native, m) {
  m.doc() = "Native kernels of recon.eval: SSIM's loss and blur on channels-last images; use recon.eval.metrics.";
  m.def("blur", &blur_py, py::arg("x"), py::arg("taps"), py::arg("threads"));
  m.def("ssim_forward", &ssim_forward_py, py::arg("a"), py::arg("b"), py::arg("taps"), py::arg("threads"));
  m.def("ssim_backward", &ssim_backward_py, py::arg("a"), py::arg("b"), py::arg("partials"), py::arg("taps"),
        py::arg("scale"), py::arg("need_a"), py::arg("need_b"), py::arg("threads"));
}
