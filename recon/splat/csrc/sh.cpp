// The basis and its gradient are evaluated for 8 Gaussians at once (lanes); the coefficient
// sums run per Gaussian over its contiguous (K,C) row.
#include "sh.h"

#include <cstring>
#include <type_traits>

namespace splat {
namespace {

constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                         -1.0925484305920792f, 0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f,
                         0.3731763325901154f,  -0.4570457994644658f, 1.445305721320277f,
                         -0.5900435899266435f};

// Basis values Y[k], k < (degree+1)^2, of the unit directions (x,y,z).
void basis8(int degree, f8 x, f8 y, f8 z, f8* Y) {
  Y[0] = splat8(C0);
  if (degree < 1) return;
  Y[1] = -C1 * y;
  Y[2] = C1 * z;
  Y[3] = -C1 * x;
  if (degree < 2) return;
  const f8 xx = x * x, yy = y * y, zz = z * z;
  Y[4] = C2[0] * x * y;
  Y[5] = C2[1] * y * z;
  Y[6] = C2[2] * (2.f * zz - xx - yy);
  Y[7] = C2[3] * x * z;
  Y[8] = C2[4] * (xx - yy);
  if (degree < 3) return;
  Y[9] = C3[0] * y * (3.f * xx - yy);
  Y[10] = C3[1] * x * y * z;
  Y[11] = C3[2] * y * (4.f * zz - xx - yy);
  Y[12] = C3[3] * z * (2.f * zz - 3.f * xx - 3.f * yy);
  Y[13] = C3[4] * x * (4.f * zz - xx - yy);
  Y[14] = C3[5] * z * (xx - yy);
  Y[15] = C3[6] * x * (xx - 3.f * yy);
}

// g = d/d(x,y,z) of sum_k W[k] Y_k(x,y,z), with x,y,z treated as independent.
void basis_grad8(int degree, f8 x, f8 y, f8 z, const f8* W, f8 g[3]) {
  g[0] = g[1] = g[2] = splat8(0.f);
  if (degree < 1) return;
  g[0] = -C1 * W[3];
  g[1] = -C1 * W[1];
  g[2] = C1 * W[2];
  if (degree < 2) return;
  const f8 xx = x * x, yy = y * y, zz = z * z;
  g[0] += C2[0] * y * W[4] - 2.f * C2[2] * x * W[6] + C2[3] * z * W[7] + 2.f * C2[4] * x * W[8];
  g[1] += C2[0] * x * W[4] + C2[1] * z * W[5] - 2.f * C2[2] * y * W[6] - 2.f * C2[4] * y * W[8];
  g[2] += C2[1] * y * W[5] + 4.f * C2[2] * z * W[6] + C2[3] * x * W[7];
  if (degree < 3) return;
  g[0] += C3[0] * 6.f * x * y * W[9] + C3[1] * y * z * W[10] - C3[2] * 2.f * x * y * W[11] -
          C3[3] * 6.f * x * z * W[12] + C3[4] * (4.f * zz - 3.f * xx - yy) * W[13] +
          C3[5] * 2.f * x * z * W[14] + C3[6] * (3.f * xx - 3.f * yy) * W[15];
  g[1] += C3[0] * (3.f * xx - 3.f * yy) * W[9] + C3[1] * x * z * W[10] +
          C3[2] * (4.f * zz - xx - 3.f * yy) * W[11] - C3[3] * 6.f * y * z * W[12] -
          C3[4] * 2.f * x * y * W[13] - C3[5] * 2.f * y * z * W[14] - C3[6] * 6.f * x * y * W[15];
  g[2] += C3[1] * x * y * W[10] + C3[2] * 8.f * y * z * W[11] +
          C3[3] * (6.f * zz - 3.f * xx - 3.f * yy) * W[12] + C3[4] * 8.f * x * z * W[13] +
          C3[5] * (xx - yy) * W[14];
}

// Rows of the block's Gaussians j < cnt, with NB = (degree+1)^2 basis functions and CC = C
// channels known at compile time (CC = 0: C at run time), so that the sums unroll into
// independent scalar chains. GCC would otherwise vectorise them with gathers over k and an
// in-order horizontal sum, which measured 3x slower than the whole rest of the projection.
#define SPLAT_NO_VECTORIZE __attribute__((optimize("no-tree-vectorize")))

// colors[j,c] = max(0.5 + sum_k Yl[k][j] sh[j,k,c], 0)
template <int NB, int CC>
SPLAT_NO_VECTORIZE void forward_rows(int cnt, int K, int C, const float* __restrict Yl,
                                     const float* __restrict sh, float* __restrict colors) {
  const int Cn = CC ? CC : C;
  for (int j = 0; j < cnt; ++j) {
    const float* s = sh + (int64_t)j * K * Cn;
    float* col = colors + (int64_t)j * Cn;
    float y[NB];
    for (int k = 0; k < NB; ++k) y[k] = Yl[k * kLanes + j];
    for (int c = 0; c < Cn; ++c) {
      float acc[4] = {0.5f, 0.f, 0.f, 0.f};  // 4 partial sums: FMA latency, not a 16-long chain
      for (int k = 0; k < NB; ++k) acc[k % 4] += y[k] * s[k * Cn + c];
      const float sum = (acc[0] + acc[1]) + (acc[2] + acc[3]);
      col[c] = sum > 0.f ? sum : 0.f;
    }
  }
}

// With g = dL/dcolour where the colour is not clamped at 0: v_sh[j,k,c] = g[c] Yl[k][j] (0 for
// k >= NB) and Wl[k][j] = sum_c g[c] sh[j,k,c].
template <int NB, int CC>
SPLAT_NO_VECTORIZE void backward_rows(int cnt, int K, int C, const float* __restrict Yl,
                                      const float* __restrict sh,
                                      const float* __restrict colors,
                                      const float* __restrict v_colors, float* __restrict v_sh,
                                      float* __restrict Wl) {
  const int Cn = CC ? CC : C;
  for (int j = 0; j < cnt; ++j) {
    const int64_t row = (int64_t)j * K * Cn;
    const float* s = sh + row;
    float* vs = v_sh + row;
    float y[NB], w[NB] = {0.f};
    for (int k = 0; k < NB; ++k) y[k] = Yl[k * kLanes + j];
    for (int c = 0; c < Cn; ++c) {
      const float g = colors[(int64_t)j * Cn + c] > 0.f ? v_colors[(int64_t)j * Cn + c] : 0.f;
      for (int k = 0; k < NB; ++k) {
        vs[k * Cn + c] = g * y[k];
        w[k] += g * s[k * Cn + c];
      }
    }
    for (int k = 0; k < NB; ++k) Wl[k * kLanes + j] = w[k];
    std::memset(vs + NB * Cn, 0, sizeof(float) * (K - NB) * Cn);
  }
}

// f(nb, cc) with nb = (degree+1)^2 and cc = C if 1 or 3 (else 0) as integral constants.
template <typename F>
void dispatch(int degree, int C, F&& f) {
  auto by_c = [&](auto nb) {
    if (C == 3)
      f(nb, std::integral_constant<int, 3>{});
    else if (C == 1)
      f(nb, std::integral_constant<int, 1>{});
    else
      f(nb, std::integral_constant<int, 0>{});
  };
  switch (degree) {
    case 0: by_c(std::integral_constant<int, 1>{}); break;
    case 1: by_c(std::integral_constant<int, 4>{}); break;
    case 2: by_c(std::integral_constant<int, 9>{}); break;
    default: by_c(std::integral_constant<int, 16>{});
  }
}

}  // namespace

ShDirs sh_dirs(const f8 dir[3]) {
  ShDirs d;
  const f8 len = sqrt8(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
  d.inv_len = select8(len > splat8(1e-20f), splat8(1.f) / len, splat8(0.f));
  for (int a = 0; a < 3; ++a) d.u[a] = dir[a] * d.inv_len;
  return d;
}

void sh_forward8(int degree, int K, int C, int cnt, const ShDirs& d, const float* sh,
                 float* colors) {
  alignas(32) f8 Y[16];
  basis8(degree, d.u[0], d.u[1], d.u[2], Y);
  const float* Yl = reinterpret_cast<const float*>(Y);
  dispatch(degree, C, [&](auto nb, auto cc) {
    forward_rows<decltype(nb)::value, decltype(cc)::value>(cnt, K, C, Yl, sh, colors);
  });
}

void sh_backward8(int degree, int K, int C, int cnt, const ShDirs& d, const float* sh,
                  const float* colors, const float* v_colors, float* v_sh, f8 v_dir[3]) {
  alignas(32) f8 Y[16];
  basis8(degree, d.u[0], d.u[1], d.u[2], Y);
  f8 W[16];
  for (f8& w : W) w = splat8(0.f);  // lanes past cnt stay 0: no gradient
  dispatch(degree, C, [&](auto nb, auto cc) {
    backward_rows<decltype(nb)::value, decltype(cc)::value>(
        cnt, K, C, reinterpret_cast<const float*>(Y), sh, colors, v_colors, v_sh,
        reinterpret_cast<float*>(W));
  });
  f8 gu[3];
  basis_grad8(degree, d.u[0], d.u[1], d.u[2], W, gu);
  // through u = dir/|dir|: (I - u u^T) gu / |dir|
  const f8 dot = gu[0] * d.u[0] + gu[1] * d.u[1] + gu[2] * d.u[2];
  for (int a = 0; a < 3; ++a) v_dir[a] += (gu[a] - dot * d.u[a]) * d.inv_len;
}

}  // namespace splat
