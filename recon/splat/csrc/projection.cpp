// Per-Gaussian projection in double precision (cheap next to the raster; keeps huge and
// degenerate scales well conditioned), stored as float.
#include "projection.h"

#include <omp.h>

#include <cmath>
#include <vector>

#include "common.h"

namespace splat {
namespace {

struct M3 {
  double m[3][3];
};

M3 matmul(const M3& a, const M3& b) {
  M3 r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      r.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
  return r;
}

M3 transpose(const M3& a) {
  M3 r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.m[i][j] = a.m[j][i];
  return r;
}

// Rotation of a unit quaternion (w,x,y,z).
M3 quat_to_rot(double w, double x, double y, double z) {
  M3 r;
  r.m[0][0] = 1 - 2 * (y * y + z * z);
  r.m[0][1] = 2 * (x * y - w * z);
  r.m[0][2] = 2 * (x * z + w * y);
  r.m[1][0] = 2 * (x * y + w * z);
  r.m[1][1] = 1 - 2 * (x * x + z * z);
  r.m[1][2] = 2 * (y * z - w * x);
  r.m[2][0] = 2 * (x * z - w * y);
  r.m[2][1] = 2 * (y * z + w * x);
  r.m[2][2] = 1 - 2 * (x * x + y * y);
  return r;
}

// Everything the forward computes for one Gaussian, recomputed by the backward.
struct Proj {
  double q[4], qnorm;  // normalised quaternion and the input's norm
  double s[3];         // scales
  M3 rq;               // rotation of the quaternion
  M3 sigma_c;          // 3D covariance in camera space
  M3 sigma_w;          // 3D covariance in world space
  double t[3];         // camera-space mean
  double u, v;         // clamped tx/tz, ty/tz
  bool u_free, v_free; // true where the clamp is inactive
  double J[2][3];
  double A, B, C, det; // 2D covariance (with blur) and its determinant
};

struct View {
  M3 R;
  double tv[3];
  double lim_xp, lim_xn, lim_yp, lim_yn;
};

View make_view(const Camera& cam) {
  View v;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) v.R.m[i][j] = cam.viewmat[4 * i + j];
    v.tv[i] = cam.viewmat[4 * i + 3];
  }
  // 3DGS clamps tx/tz to 1.3 tan(fov/2); with an off-centre principal point the two sides
  // differ (as gsplat): the image edge plus 0.3 tan(fov/2) of margin on each side.
  const double tan_x = 0.5 * cam.width / cam.fx, tan_y = 0.5 * cam.height / cam.fy;
  v.lim_xp = (cam.width - cam.cx) / cam.fx + 0.3 * tan_x;
  v.lim_xn = cam.cx / cam.fx + 0.3 * tan_x;
  v.lim_yp = (cam.height - cam.cy) / cam.fy + 0.3 * tan_y;
  v.lim_yn = cam.cy / cam.fy + 0.3 * tan_y;
  return v;
}

// Camera-space mean only (decides near-plane culling before the rest is computed).
void camera_mean(const View& view, const float* mean, double t[3]) {
  for (int i = 0; i < 3; ++i)
    t[i] = view.R.m[i][0] * mean[0] + view.R.m[i][1] * mean[1] + view.R.m[i][2] * mean[2] +
           view.tv[i];
}

void compute_proj(const View& view, const Camera& cam, const float* mean, const float* quat,
                  const float* log_scale, Proj& p) {
  camera_mean(view, mean, p.t);
  double qn = std::sqrt((double)quat[0] * quat[0] + (double)quat[1] * quat[1] +
                        (double)quat[2] * quat[2] + (double)quat[3] * quat[3]);
  p.qnorm = qn;
  if (qn < 1e-30) {  // a zero quaternion means no rotation (and gets no gradient)
    p.q[0] = 1;
    p.q[1] = p.q[2] = p.q[3] = 0;
  } else {
    for (int i = 0; i < 4; ++i) p.q[i] = quat[i] / qn;
  }
  p.rq = quat_to_rot(p.q[0], p.q[1], p.q[2], p.q[3]);
  for (int i = 0; i < 3; ++i) p.s[i] = std::exp((double)log_scale[i]);
  // sigma_w = (Rq S)(Rq S)^T
  M3 m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m.m[i][j] = p.rq.m[i][j] * p.s[j];
  p.sigma_w = matmul(m, transpose(m));
  p.sigma_c = matmul(matmul(view.R, p.sigma_w), transpose(view.R));
  const double tz = p.t[2];
  const double rx = p.t[0] / tz, ry = p.t[1] / tz;
  p.u = std::min(view.lim_xp, std::max(-view.lim_xn, rx));
  p.v = std::min(view.lim_yp, std::max(-view.lim_yn, ry));
  p.u_free = rx > -view.lim_xn && rx < view.lim_xp;
  p.v_free = ry > -view.lim_yn && ry < view.lim_yp;
  p.J[0][0] = cam.fx / tz;
  p.J[0][1] = 0;
  p.J[0][2] = -cam.fx * p.u / tz;
  p.J[1][0] = 0;
  p.J[1][1] = cam.fy / tz;
  p.J[1][2] = -cam.fy * p.v / tz;
  double js[2][3];  // J sigma_c
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j)
      js[i][j] = p.J[i][0] * p.sigma_c.m[0][j] + p.J[i][1] * p.sigma_c.m[1][j] +
                 p.J[i][2] * p.sigma_c.m[2][j];
  double c2[2][2];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      c2[i][j] = js[i][0] * p.J[j][0] + js[i][1] * p.J[j][1] + js[i][2] * p.J[j][2];
  p.A = c2[0][0] + kBlur;
  p.B = c2[0][1];
  p.C = c2[1][1] + kBlur;
  p.det = p.A * p.C - p.B * p.B;
}

}  // namespace

void project_forward(int64_t n, const float* means, const float* quats, const float* log_scales,
                     const float* opacities, const Camera& cam, float* means2d, float* conics,
                     float* depths, int32_t* radii, int threads) {
  const View view = make_view(cam);
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1024)
  for (int64_t i = 0; i < n; ++i) {
    means2d[2 * i] = means2d[2 * i + 1] = 0.f;
    conics[3 * i] = conics[3 * i + 1] = conics[3 * i + 2] = 0.f;
    radii[i] = 0;
    double t[3];
    camera_mean(view, means + 3 * i, t);
    depths[i] = (float)t[2];
    if (!(t[2] >= cam.near_plane)) continue;
    Proj p;
    compute_proj(view, cam, means + 3 * i, quats + 4 * i, log_scales + 3 * i, p);
    if (!(p.det > 0.0)) continue;
    const float mx = (float)(cam.fx * p.t[0] / p.t[2] + cam.cx);
    const float my = (float)(cam.fy * p.t[1] / p.t[2] + cam.cy);
    const float ca = (float)(p.C / p.det), cb = (float)(-p.B / p.det), cc = (float)(p.A / p.det);
    int32_t box[4];
    if (!gaussian_bbox(mx, my, ca, cb, cc, opacities[i], cam.width, cam.height, box)) continue;
    means2d[2 * i] = mx;
    means2d[2 * i + 1] = my;
    conics[3 * i] = ca;
    conics[3 * i + 1] = cb;
    conics[3 * i + 2] = cc;
    // Reported radius: the opacity-aware extent along the major axis, at least 1.
    const double r2 = 2.0 * std::log(255.0 * (double)opacities[i]);
    const double lmax =
        0.5 * (p.A + p.C) + std::sqrt(0.25 * (p.A - p.C) * (p.A - p.C) + p.B * p.B);
    const double r = std::ceil(std::sqrt(std::max(0.0, r2) * lmax));
    radii[i] = (int32_t)std::max(1.0, std::min(r, 2147483647.0));
  }
}

void project_backward(int64_t n, const float* means, const float* quats, const float* log_scales,
                      const int32_t* radii, const Camera& cam, const float* v_means2d,
                      const float* v_conics, const float* v_depths, float* v_means,
                      float* v_quats, float* v_log_scales, float* v_viewmat, int threads) {
  const View view = make_view(cam);
  const int nt = std::max(1, threads);
  std::vector<double> v_view_acc(12 * nt, 0.0);  // per-thread dL/dR (9) and dL/dtv (3)
#pragma omp parallel num_threads(nt)
  {
    double* vacc = v_view_acc.data() + 12 * omp_get_thread_num();
#pragma omp for schedule(dynamic, 1024)
    for (int64_t i = 0; i < n; ++i) {
      float* vm = v_means + 3 * i;
      float* vq = v_quats + 4 * i;
      float* vs = v_log_scales + 3 * i;
      vm[0] = vm[1] = vm[2] = 0.f;
      vq[0] = vq[1] = vq[2] = vq[3] = 0.f;
      vs[0] = vs[1] = vs[2] = 0.f;
      if (radii[i] <= 0) continue;
      Proj p;
      compute_proj(view, cam, means + 3 * i, quats + 4 * i, log_scales + 3 * i, p);
      const double tx = p.t[0], ty = p.t[1], tz = p.t[2];
      double v_t[3] = {0, 0, 0};
      // means2d = (fx tx/tz + cx, fy ty/tz + cy); depth = tz
      const double gmx = v_means2d[2 * i], gmy = v_means2d[2 * i + 1];
      v_t[0] += gmx * cam.fx / tz;
      v_t[1] += gmy * cam.fy / tz;
      v_t[2] += -gmx * cam.fx * tx / (tz * tz) - gmy * cam.fy * ty / (tz * tz) + v_depths[i];
      // conic (a,b,c) = (C, -B, A)/det  ->  gradient of the 2D covariance (A, B, C)
      const double ga = v_conics[3 * i], gb = v_conics[3 * i + 1], gc = v_conics[3 * i + 2];
      const double A = p.A, B = p.B, C = p.C, d2 = p.det * p.det, id = 1.0 / p.det;
      const double gA = ga * (-C * C / d2) + gb * (B * C / d2) + gc * (-B * B / d2);
      const double gB = ga * (2 * B * C / d2) + gb * (-id - 2 * B * B / d2) + gc * (2 * A * B / d2);
      const double gC = ga * (-B * B / d2) + gb * (A * B / d2) + gc * (-A * A / d2);
      // cov2d = J Sc J^T: G2 is dL/dcov2d as a symmetric matrix (B appears twice).
      const double G2[2][2] = {{gA, 0.5 * gB}, {0.5 * gB, gC}};
      // dL/dSc = J^T G2 J
      double G2J[2][3];
      for (int a = 0; a < 2; ++a)
        for (int j = 0; j < 3; ++j) G2J[a][j] = G2[a][0] * p.J[0][j] + G2[a][1] * p.J[1][j];
      M3 gSc;
      for (int i2 = 0; i2 < 3; ++i2)
        for (int j = 0; j < 3; ++j) gSc.m[i2][j] = p.J[0][i2] * G2J[0][j] + p.J[1][i2] * G2J[1][j];
      // dL/dJ = 2 G2 J Sc
      double gJ[2][3];
      for (int a = 0; a < 2; ++a)
        for (int j = 0; j < 3; ++j)
          gJ[a][j] = 2 * (G2J[a][0] * p.sigma_c.m[0][j] + G2J[a][1] * p.sigma_c.m[1][j] +
                          G2J[a][2] * p.sigma_c.m[2][j]);
      // J00 = fx/tz, J02 = -fx u/tz with u = clamp(tx/tz); same for y.
      v_t[2] += gJ[0][0] * (-cam.fx / (tz * tz)) + gJ[1][1] * (-cam.fy / (tz * tz));
      v_t[2] += gJ[0][2] * (cam.fx * p.u / (tz * tz)) + gJ[1][2] * (cam.fy * p.v / (tz * tz));
      const double g_u = gJ[0][2] * (-cam.fx / tz), g_v = gJ[1][2] * (-cam.fy / tz);
      if (p.u_free) {
        v_t[0] += g_u / tz;
        v_t[2] += -g_u * tx / (tz * tz);
      }
      if (p.v_free) {
        v_t[1] += g_v / tz;
        v_t[2] += -g_v * ty / (tz * tz);
      }
      // Sc = R Sw R^T: dL/dSw = R^T gSc R; dL/dR += 2 gSc R Sw
      const M3 Rt = transpose(view.R);
      const M3 gSw = matmul(matmul(Rt, gSc), view.R);
      const M3 gR = matmul(matmul(gSc, view.R), p.sigma_w);
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) vacc[3 * a + b] += 2 * gR.m[a][b];
      // t = R m + tv
      for (int a = 0; a < 3; ++a) {
        vm[a] = (float)(view.R.m[0][a] * v_t[0] + view.R.m[1][a] * v_t[1] +
                        view.R.m[2][a] * v_t[2]);
        for (int b = 0; b < 3; ++b) vacc[3 * a + b] += v_t[a] * means[3 * i + b];
        vacc[9 + a] += v_t[a];
      }
      // Sw = M M^T with M = Rq S: dL/dM = 2 gSw M
      M3 M;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) M.m[a][b] = p.rq.m[a][b] * p.s[b];
      const M3 gM = matmul(gSw, M);  // times 2 below
      double gRq[3][3];
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) gRq[a][b] = 2 * gM.m[a][b] * p.s[b];
      for (int b = 0; b < 3; ++b) {
        double gs = 0;
        for (int a = 0; a < 3; ++a) gs += 2 * gM.m[a][b] * p.rq.m[a][b];
        vs[b] = (float)(gs * p.s[b]);  // d exp(l)/dl = exp(l)
      }
      // rotation of the unit quaternion -> gradient of (w,x,y,z)
      if (p.qnorm >= 1e-30) {
        const double w = p.q[0], x = p.q[1], y = p.q[2], z = p.q[3];
        const double(*g)[3] = gRq;
        double gq[4];
        gq[0] = 2 * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] +
                     x * g[2][1]);
        gq[1] = 2 * (y * g[0][1] + z * g[0][2] + y * g[1][0] - 2 * x * g[1][1] + w * -g[1][2] +
                     z * g[2][0] + w * g[2][1] - 2 * x * g[2][2]);
        gq[2] = 2 * (-2 * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2] -
                     w * g[2][0] + z * g[2][1] - 2 * y * g[2][2]);
        gq[3] = 2 * (-2 * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] -
                     2 * z * g[1][1] + y * g[1][2] + x * g[2][0] + y * g[2][1]);
        // through q/|q|: (I - q q^T) g / |q|
        const double dot = gq[0] * w + gq[1] * x + gq[2] * y + gq[3] * z;
        for (int a = 0; a < 4; ++a) vq[a] = (float)((gq[a] - dot * p.q[a]) / p.qnorm);
      }
    }
  }
  if (v_viewmat) {
    for (int k = 0; k < 16; ++k) v_viewmat[k] = 0.f;
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        double s = 0;
        for (int t = 0; t < nt; ++t) s += v_view_acc[12 * t + 3 * a + b];
        v_viewmat[4 * a + b] = (float)s;
      }
      double s = 0;
      for (int t = 0; t < nt; ++t) s += v_view_acc[12 * t + 9 + a];
      v_viewmat[4 * a + 3] = (float)s;
    }
  }
}

}  // namespace splat
