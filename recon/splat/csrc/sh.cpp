#include "sh.h"

#include <cmath>

namespace splat {
namespace {

constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                         -1.0925484305920792f, 0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f,
                         0.3731763325901154f,  -0.4570457994644658f, 1.445305721320277f,
                         -0.5900435899266435f};

// Basis values Y[k] and, if dY is given, their partial derivatives in (x,y,z) of the unit
// direction (as if x,y,z were independent; the normalisation is applied by the caller).
void sh_basis(int degree, float x, float y, float z, float* Y, float (*dY)[3]) {
  Y[0] = C0;
  if (dY) dY[0][0] = dY[0][1] = dY[0][2] = 0.f;
  if (degree < 1) return;
  Y[1] = -C1 * y;
  Y[2] = C1 * z;
  Y[3] = -C1 * x;
  if (dY) {
    dY[1][0] = 0; dY[1][1] = -C1; dY[1][2] = 0;
    dY[2][0] = 0; dY[2][1] = 0; dY[2][2] = C1;
    dY[3][0] = -C1; dY[3][1] = 0; dY[3][2] = 0;
  }
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z;
  Y[4] = C2[0] * x * y;
  Y[5] = C2[1] * y * z;
  Y[6] = C2[2] * (2 * zz - xx - yy);
  Y[7] = C2[3] * x * z;
  Y[8] = C2[4] * (xx - yy);
  if (dY) {
    dY[4][0] = C2[0] * y; dY[4][1] = C2[0] * x; dY[4][2] = 0;
    dY[5][0] = 0; dY[5][1] = C2[1] * z; dY[5][2] = C2[1] * y;
    dY[6][0] = -2 * C2[2] * x; dY[6][1] = -2 * C2[2] * y; dY[6][2] = 4 * C2[2] * z;
    dY[7][0] = C2[3] * z; dY[7][1] = 0; dY[7][2] = C2[3] * x;
    dY[8][0] = 2 * C2[4] * x; dY[8][1] = -2 * C2[4] * y; dY[8][2] = 0;
  }
  if (degree < 3) return;
  Y[9] = C3[0] * y * (3 * xx - yy);
  Y[10] = C3[1] * x * y * z;
  Y[11] = C3[2] * y * (4 * zz - xx - yy);
  Y[12] = C3[3] * z * (2 * zz - 3 * xx - 3 * yy);
  Y[13] = C3[4] * x * (4 * zz - xx - yy);
  Y[14] = C3[5] * z * (xx - yy);
  Y[15] = C3[6] * x * (xx - 3 * yy);
  if (dY) {
    dY[9][0] = C3[0] * 6 * x * y; dY[9][1] = C3[0] * (3 * xx - 3 * yy); dY[9][2] = 0;
    dY[10][0] = C3[1] * y * z; dY[10][1] = C3[1] * x * z; dY[10][2] = C3[1] * x * y;
    dY[11][0] = C3[2] * -2 * x * y; dY[11][1] = C3[2] * (4 * zz - xx - 3 * yy);
    dY[11][2] = C3[2] * 8 * y * z;
    dY[12][0] = C3[3] * -6 * x * z; dY[12][1] = C3[3] * -6 * y * z;
    dY[12][2] = C3[3] * (6 * zz - 3 * xx - 3 * yy);
    dY[13][0] = C3[4] * (4 * zz - 3 * xx - yy); dY[13][1] = C3[4] * -2 * x * y;
    dY[13][2] = C3[4] * 8 * x * z;
    dY[14][0] = C3[5] * 2 * x * z; dY[14][1] = C3[5] * -2 * y * z; dY[14][2] = C3[5] * (xx - yy);
    dY[15][0] = C3[6] * (3 * xx - 3 * yy); dY[15][1] = C3[6] * -6 * x * y; dY[15][2] = 0;
  }
}

// Unit direction; a zero vector gives (0,0,0) so only the degree-0 term survives.
float unit(const float* d, float u[3]) {
  const float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  const float inv = len > 1e-20f ? 1.f / len : 0.f;
  for (int i = 0; i < 3; ++i) u[i] = d[i] * inv;
  return len;
}

}  // namespace

void sh_forward(int64_t n, int K, int C, int degree, const float* sh, const float* dirs,
                float* colors, int threads) {
  const int nb = (degree + 1) * (degree + 1);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 2048)
  for (int64_t i = 0; i < n; ++i) {
    float u[3], Y[16];
    unit(dirs + 3 * i, u);
    sh_basis(degree, u[0], u[1], u[2], Y, nullptr);
    const float* s = sh + i * (int64_t)K * C;
    for (int c = 0; c < C; ++c) {
      float acc = 0.5f;
      for (int k = 0; k < nb; ++k) acc += Y[k] * s[k * C + c];
      colors[i * C + c] = acc > 0.f ? acc : 0.f;
    }
  }
}

void sh_backward(int64_t n, int K, int C, int degree, const float* sh, const float* dirs,
                 const float* colors, const float* v_colors, float* v_sh, float* v_dirs,
                 int threads) {
  const int nb = (degree + 1) * (degree + 1);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 2048)
  for (int64_t i = 0; i < n; ++i) {
    float u[3], Y[16], dY[16][3];
    const float len = unit(dirs + 3 * i, u);
    sh_basis(degree, u[0], u[1], u[2], Y, dY);
    const float* s = sh + i * (int64_t)K * C;
    float* vs = v_sh + i * (int64_t)K * C;
    for (int k = 0; k < K * C; ++k) vs[k] = 0.f;
    float gu[3] = {0.f, 0.f, 0.f};
    for (int c = 0; c < C; ++c) {
      // colour = max(x, 0): no gradient where the clamp is active
      const float g = colors[i * C + c] > 0.f ? v_colors[i * C + c] : 0.f;
      if (g == 0.f) continue;
      for (int k = 0; k < nb; ++k) {
        vs[k * C + c] = g * Y[k];
        gu[0] += g * s[k * C + c] * dY[k][0];
        gu[1] += g * s[k * C + c] * dY[k][1];
        gu[2] += g * s[k * C + c] * dY[k][2];
      }
    }
    // through u = d/|d|: (I - u u^T) gu / |d|
    float* vd = v_dirs + 3 * i;
    if (len > 1e-20f) {
      const float dot = gu[0] * u[0] + gu[1] * u[1] + gu[2] * u[2];
      for (int a = 0; a < 3; ++a) vd[a] = (gu[a] - dot * u[a]) / len;
    } else {
      vd[0] = vd[1] = vd[2] = 0.f;
    }
  }
}

}  // namespace splat
