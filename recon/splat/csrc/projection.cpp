// Eight Gaussians per step, one per lane of an f8 (AVX2), with the SH colour in the same pass
// (one read of each Gaussian). Float, except where the former per-Gaussian double code
// measurably needed its precision (stress test: 20k Gaussians, log-scales in [-18, 2], i.e.
// flat and needle-like ones seen edge-on):
// - camera-space and pixel means (float doubled the pixel-mean error, to 8e-5 px at 640x480);
// - cov2d = P P^T + blur I (P = J R_view Rq S, float) and its inverse, the conic: near-singular
//   covariances cancel in A C - B^2, and float put q = d^T conic d off by up to 3x the error
//   of merely storing the exact conic as float; in double it is at that floor;
// - the conic's VJP -Q G Q and its product with P (float lost 30x on quaternion gradients);
// - the camera position and the viewmat gradient sums.
// Quaternions are scaled by their largest component before normalising (no underflow).
#include "projection.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "common.h"
#include "sh.h"

namespace splat {
namespace {

constexpr int64_t kChunk = 1024;  // Gaussians per scheduling unit

typedef double d8 __attribute__((vector_size(64)));  // 8 double lanes (two AVX2 registers)
inline d8 to_d8(f8 x) { return __builtin_convertvector(x, d8); }
inline f8 to_f8(d8 x) { return __builtin_convertvector(x, f8); }

struct View {
  float R[3][3], tv[3], campos[3];
  double Rd[3][3], tvd[3];
  float fx, fy, cx, cy;
  float lim_xp, lim_xn, lim_yp, lim_yn;  // clamp of tx/tz and ty/tz in the Jacobian
};

View make_view(const Camera& cam) {
  View v;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) v.R[i][j] = v.Rd[i][j] = cam.viewmat[4 * i + j];
    v.tv[i] = v.tvd[i] = cam.viewmat[4 * i + 3];
  }
  for (int j = 0; j < 3; ++j) {  // campos = -R^T tv
    double c = 0;
    for (int i = 0; i < 3; ++i) c -= (double)cam.viewmat[4 * i + j] * cam.viewmat[4 * i + 3];
    v.campos[j] = (float)c;
  }
  v.fx = cam.fx;
  v.fy = cam.fy;
  v.cx = cam.cx;
  v.cy = cam.cy;
  // 3DGS clamps tx/tz to 1.3 tan(fov/2); with an off-centre principal point the two sides
  // differ (as gsplat): the image edge plus 0.3 tan(fov/2) of margin on each side.
  // Of the full view when the image is a window of it.
  const double w = cam.full_width, h = cam.full_height;
  const double cx = (double)cam.cx + cam.win_x0, cy = (double)cam.cy + cam.win_y0;
  const double tan_x = 0.5 * w / cam.fx, tan_y = 0.5 * h / cam.fy;
  v.lim_xp = (float)((w - cx) / cam.fx + 0.3 * tan_x);
  v.lim_xn = (float)(cx / cam.fx + 0.3 * tan_x);
  v.lim_yp = (float)((h - cy) / cam.fy + 0.3 * tan_y);
  v.lim_yn = (float)(cy / cam.fy + 0.3 * tan_y);
  return v;
}

// Lane j < cnt: a[stride * (i0 + j) + k]; lanes past cnt repeat the last Gaussian (computed,
// never stored).
template <typename T, typename V>
inline V gather(const T* a, int stride, int64_t i0, int cnt, int k) {
  V r;
  for (int j = 0; j < kLanes; ++j) r[j] = a[stride * (i0 + std::min(j, cnt - 1)) + k];
  return r;
}
inline f8 gatherf(const float* a, int stride, int64_t i0, int cnt, int k) {
  return gather<float, f8>(a, stride, i0, cnt, k);
}
inline void scatter(f8 v, float* a, int stride, int64_t i0, int cnt, int k) {
  for (int j = 0; j < cnt; ++j) a[stride * (i0 + j) + k] = v[j];
}

const i8 kLaneIndex = {0, 1, 2, 3, 4, 5, 6, 7};

inline f8 abs8(f8 x) { return x < splat8(0.f) ? -x : x; }

// Forward quantities of one block of Gaussians, recomputed by the backward.
struct Block {
  f8 m[3];            // world mean
  f8 t[3], rz;        // camera-space mean, 1/tz
  f8 mx, my;          // pixel mean (rounded once from double)
  f8 u, v;            // tx/tz, ty/tz clamped (Jacobian)
  i8 u_free, v_free;  // the clamp is inactive
  f8 q[4], qnorm;     // unit quaternion; the input's norm (0: zero quaternion = identity)
  f8 s[3];            // scales
  f8 Rq[3][3];        // rotation of q
  f8 T[2][3];         // J R_view
  f8 TR[2][3];        // T Rq
  f8 P[2][3];         // TR diag(s): cov2d = P P^T + blur I
  f8 A, B, C;         // cov2d with blur
  f8 det;             // det(cov2d)
  f8 ca, cb, cc;      // conic = cov2d^-1
};

void project_block(const View& v, const float* means, const float* quats,
                   const float* log_scales, int64_t i0, int cnt, Block& b) {
  d8 md[3], td[3];
  for (int a = 0; a < 3; ++a) {
    b.m[a] = gatherf(means, 3, i0, cnt, a);
    md[a] = to_d8(b.m[a]);
  }
  for (int i = 0; i < 3; ++i) {
    td[i] = v.Rd[i][0] * md[0] + v.Rd[i][1] * md[1] + v.Rd[i][2] * md[2] + v.tvd[i];
    b.t[i] = to_f8(td[i]);
  }
  const d8 rzd = 1.0 / td[2], rxd = td[0] * rzd, ryd = td[1] * rzd;
  b.rz = to_f8(rzd);
  b.mx = to_f8(v.fx * rxd + v.cx);
  b.my = to_f8(v.fy * ryd + v.cy);
  const f8 rx = to_f8(rxd), ry = to_f8(ryd);
  b.u = min8(max8(rx, splat8(-v.lim_xn)), splat8(v.lim_xp));
  b.v = min8(max8(ry, splat8(-v.lim_yn)), splat8(v.lim_yp));
  b.u_free = (rx > -v.lim_xn) & (rx < v.lim_xp);
  b.v_free = (ry > -v.lim_yn) & (ry < v.lim_yp);

  f8 q[4];
  for (int k = 0; k < 4; ++k) q[k] = gatherf(quats, 4, i0, cnt, k);
  const f8 qmax = max8(max8(abs8(q[0]), abs8(q[1])), max8(abs8(q[2]), abs8(q[3])));
  const i8 qzero = qmax < splat8(1e-30f);  // a zero quaternion means no rotation
  const f8 qinv = select8(qzero, splat8(0.f), splat8(1.f) / qmax);
  for (int k = 0; k < 4; ++k) q[k] *= qinv;
  const f8 qn = sqrt8(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const f8 qninv = select8(qzero, splat8(0.f), splat8(1.f) / qn);
  for (int k = 0; k < 4; ++k) b.q[k] = q[k] * qninv;
  b.q[0] = select8(qzero, splat8(1.f), b.q[0]);
  b.qnorm = select8(qzero, splat8(0.f), qmax * qn);
  const f8 w = b.q[0], x = b.q[1], y = b.q[2], z = b.q[3];
  b.Rq[0][0] = 1.f - 2.f * (y * y + z * z);
  b.Rq[0][1] = 2.f * (x * y - w * z);
  b.Rq[0][2] = 2.f * (x * z + w * y);
  b.Rq[1][0] = 2.f * (x * y + w * z);
  b.Rq[1][1] = 1.f - 2.f * (x * x + z * z);
  b.Rq[1][2] = 2.f * (y * z - w * x);
  b.Rq[2][0] = 2.f * (x * z - w * y);
  b.Rq[2][1] = 2.f * (y * z + w * x);
  b.Rq[2][2] = 1.f - 2.f * (x * x + y * y);
  for (int j = 0; j < 3; ++j) b.s[j] = expf8(gatherf(log_scales, 3, i0, cnt, j));

  const f8 fxr = v.fx * b.rz, fyr = v.fy * b.rz;
  for (int k = 0; k < 3; ++k) {
    b.T[0][k] = fxr * (v.R[0][k] - b.u * v.R[2][k]);
    b.T[1][k] = fyr * (v.R[1][k] - b.v * v.R[2][k]);
  }
  for (int a = 0; a < 2; ++a)
    for (int j = 0; j < 3; ++j) {
      b.TR[a][j] = b.T[a][0] * b.Rq[0][j] + b.T[a][1] * b.Rq[1][j] + b.T[a][2] * b.Rq[2][j];
      b.P[a][j] = b.TR[a][j] * b.s[j];
    }
  // cov2d and its inverse in double (see the top of the file)
  d8 Pd[2][3];
  for (int a = 0; a < 2; ++a)
    for (int j = 0; j < 3; ++j) Pd[a][j] = to_d8(b.P[a][j]);
  const d8 A = Pd[0][0] * Pd[0][0] + Pd[0][1] * Pd[0][1] + Pd[0][2] * Pd[0][2] + kBlur;
  const d8 B = Pd[0][0] * Pd[1][0] + Pd[0][1] * Pd[1][1] + Pd[0][2] * Pd[1][2];
  const d8 C = Pd[1][0] * Pd[1][0] + Pd[1][1] * Pd[1][1] + Pd[1][2] * Pd[1][2] + kBlur;
  const d8 det = A * C - B * B;
  b.A = to_f8(A);
  b.B = to_f8(B);
  b.C = to_f8(C);
  b.det = to_f8(det);
  b.ca = to_f8(C / det);
  b.cb = to_f8(-B / det);
  b.cc = to_f8(A / det);
}

}  // namespace

void project_forward(int64_t n, const float* means, const float* quats, const float* log_scales,
                     const float* opacities, const Camera& cam, const ShInput& sh,
                     float* means2d, float* conics, float* depths, int32_t* radii,
                     float* colors, int threads) {
  const View v = make_view(cam);
  const int64_t n_chunks = (n + kChunk - 1) / kChunk;
  const int64_t sh_row = (int64_t)sh.K * sh.C;
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(dynamic, 1)
  for (int64_t chunk = 0; chunk < n_chunks; ++chunk) {
    const int64_t end = std::min(n, (chunk + 1) * kChunk);
    for (int64_t i0 = chunk * kChunk; i0 < end; i0 += kLanes) {
      const int cnt = (int)std::min<int64_t>(kLanes, end - i0);
      Block b;
      project_block(v, means, quats, log_scales, i0, cnt, b);
      const f8 o = gatherf(opacities, 1, i0, cnt, 0);
      const f8 mx = b.mx, my = b.my;
      // alpha = o exp(-q/2) can reach 1/255 where q <= r2 = 2 ln(255 o)
      const f8 r2 = 2.f * log8(max8(255.f * o, splat8(1.f)));
      // Cull with gaussian_bbox's pixel box (which the rasterizer applies exactly), widened by
      // far more than float rounding: nothing the rasterizer would draw is culled here.
      const f8 rb = r2 * (float)kReachScale + (float)kReachPad;
      const f8 ex = sqrt8(rb * b.A) * 1.0001f + 1e-3f, ey = sqrt8(rb * b.C) * 1.0001f + 1e-3f;
      const f8 x0 = ceil8(mx - ex - 0.5f), x1 = floor8(mx + ex - 0.5f);
      const f8 y0 = ceil8(my - ey - 0.5f), y1 = floor8(my + ey - 0.5f);
      i8 vis = (b.t[2] >= splat8(cam.near_plane)) & (o >= splat8(kAlphaMin)) &
               (b.det > splat8(0.f)) & (b.det <= splat8(3.4e38f)) &
               (x1 >= splat8(0.f)) & (x0 <= x1) &
               (x0 <= splat8(cam.width - 1.f)) & (y1 >= splat8(0.f)) & (y0 <= y1) &
               (y0 <= splat8(cam.height - 1.f));
      if (cam.beside >= 0.f) {  // the centre in the full view's pixels, as the window's clamp
        const f8 px = mx + (float)cam.win_x0, py = my + (float)cam.win_y0;
        const float W = (float)cam.full_width, H = (float)cam.full_height;
        vis &= (px >= splat8(-cam.beside * W)) & (px <= splat8((1.f + cam.beside) * W)) &
               (py >= splat8(-cam.beside * H)) & (py <= splat8((1.f + cam.beside) * H));
      }
      const f8 zero = splat8(0.f);
      scatter(select8(vis, mx, zero), means2d, 2, i0, cnt, 0);
      scatter(select8(vis, my, zero), means2d, 2, i0, cnt, 1);
      scatter(select8(vis, b.ca, zero), conics, 3, i0, cnt, 0);
      scatter(select8(vis, b.cb, zero), conics, 3, i0, cnt, 1);
      scatter(select8(vis, b.cc, zero), conics, 3, i0, cnt, 2);
      scatter(b.t[2], depths, 1, i0, cnt, 0);
      // Reported radius: the opacity-aware extent along the major axis, at least 1.
      const f8 lmax = 0.5f * (b.A + b.C) +
                      sqrt8(0.25f * (b.A - b.C) * (b.A - b.C) + b.B * b.B);
      const f8 r = ceil8(sqrt8(max8(r2, zero) * lmax));
      const f8 r_int = min8(max8(r, splat8(1.f)), splat8(2147483520.f));  // < 2^31 as float
      const i8 rad = __builtin_convertvector(r_int, i8);
      for (int j = 0; j < cnt; ++j) radii[i0 + j] = vis[j] ? rad[j] : 0;
      if (sh.sh) {
        const f8 dir[3] = {b.m[0] - v.campos[0], b.m[1] - v.campos[1], b.m[2] - v.campos[2]};
        sh_forward8(sh.degree, sh.K, sh.C, cnt, sh_dirs(dir), sh.sh + i0 * sh_row,
                    colors + i0 * sh.C);
      }
    }
  }
}

void project_backward(int64_t n, const float* means, const float* quats, const float* log_scales,
                      const int32_t* radii, const Camera& cam, const ShInput& sh,
                      const float* colors, const float* v_means2d, const float* v_conics,
                      const float* v_depths, const float* v_colors, float* v_means,
                      float* v_quats, float* v_log_scales, float* v_viewmat, float* v_sh,
                      int threads) {
  const View v = make_view(cam);
  const int nt = std::max(1, threads);
  const int64_t n_chunks = (n + kChunk - 1) / kChunk;
  const int64_t sh_row = (int64_t)sh.K * sh.C;
  // Per chunk: dL/dR_view (9), dL/dtv (3), sum of dL/d(view direction) (3), summed in chunk
  // order afterwards (the same bits whichever thread took a chunk). Every per-Gaussian gradient
  // is written by exactly one thread, so nothing else needs a reduction.
  constexpr int kAcc = 15;
  std::vector<double> acc_view((size_t)kAcc * n_chunks, 0.0);
#pragma omp parallel num_threads(nt)
  {
#pragma omp for schedule(dynamic, 1)
    for (int64_t chunk = 0; chunk < n_chunks; ++chunk) {
      double* acc = acc_view.data() + (size_t)kAcc * chunk;
      f8 lane_acc[kAcc];
      for (f8& a : lane_acc) a = splat8(0.f);
      const int64_t end = std::min(n, (chunk + 1) * kChunk);
      for (int64_t i0 = chunk * kChunk; i0 < end; i0 += kLanes) {
        const int cnt = (int)std::min<int64_t>(kLanes, end - i0);
        Block b;
        project_block(v, means, quats, log_scales, i0, cnt, b);
        // padding lanes (past cnt) repeat a Gaussian: keep them out of the viewmat sums
        const i8 vis = (gather<int32_t, i8>(radii, 1, i0, cnt, 0) > spliti8(0)) &
                       (kLaneIndex < spliti8(cnt));
        const f8 gmx = gatherf(v_means2d, 2, i0, cnt, 0);
        const f8 gmy = gatherf(v_means2d, 2, i0, cnt, 1);
        const f8 ga = gatherf(v_conics, 3, i0, cnt, 0), gb = gatherf(v_conics, 3, i0, cnt, 1);
        const f8 gc = gatherf(v_conics, 3, i0, cnt, 2), gz = gatherf(v_depths, 1, i0, cnt, 0);
        // conic Q = cov^-1 -> dL/dcov = -Q G Q with G = [[ga, gb/2], [gb/2, gc]] (b is shared);
        // cov = P P^T + blur -> dL/dP = 2 V P. Double: for a near-singular cov, V is large and
        // the rows of P nearly parallel, and V P cancels (float lost 30x on quats, log-scales).
        const d8 ca = to_d8(b.ca), cb = to_d8(b.cb), cc = to_d8(b.cc);
        const d8 ga_d = to_d8(ga), hb = 0.5 * to_d8(gb), gc_d = to_d8(gc);
        const d8 X00 = ca * ga_d + cb * hb, X01 = ca * hb + cb * gc_d;
        const d8 X10 = cb * ga_d + cc * hb, X11 = cb * hb + cc * gc_d;
        const d8 V00 = -(X00 * ca + X01 * cb), V01 = -(X00 * cb + X01 * cc);
        const d8 V11 = -(X10 * cb + X11 * cc);
        // P = TR diag(s)
        f8 vTR[2][3], vs[3];
        for (int j = 0; j < 3; ++j) {
          const d8 P0 = to_d8(b.P[0][j]), P1 = to_d8(b.P[1][j]);
          const f8 vP0 = to_f8(2.0 * (V00 * P0 + V01 * P1));
          const f8 vP1 = to_f8(2.0 * (V01 * P0 + V11 * P1));
          vTR[0][j] = vP0 * b.s[j];
          vTR[1][j] = vP1 * b.s[j];
          vs[j] = vP0 * b.TR[0][j] + vP1 * b.TR[1][j];
        }
        // TR = T Rq
        f8 vT[2][3], vRq[3][3];
        for (int a = 0; a < 2; ++a)
          for (int k = 0; k < 3; ++k)
            vT[a][k] = vTR[a][0] * b.Rq[k][0] + vTR[a][1] * b.Rq[k][1] + vTR[a][2] * b.Rq[k][2];
        for (int k = 0; k < 3; ++k)
          for (int j = 0; j < 3; ++j) vRq[k][j] = b.T[0][k] * vTR[0][j] + b.T[1][k] * vTR[1][j];
        // T0k = fx rz (R0k - u R2k), T1k = fy rz (R1k - v R2k)
        const f8 fxr = v.fx * b.rz, fyr = v.fy * b.rz;
        f8 vR[3][3], v_rz = splat8(0.f), v_u = v_rz, v_v = v_rz;
        for (int k = 0; k < 3; ++k) {
          vR[0][k] = vT[0][k] * fxr;
          vR[1][k] = vT[1][k] * fyr;
          vR[2][k] = -(vR[0][k] * b.u + vR[1][k] * b.v);
          v_rz += vT[0][k] * v.fx * (v.R[0][k] - b.u * v.R[2][k]) +
                  vT[1][k] * v.fy * (v.R[1][k] - b.v * v.R[2][k]);
          v_u -= vR[0][k] * v.R[2][k];
          v_v -= vR[1][k] * v.R[2][k];
        }
        // means2d = (fx tx rz + cx, fy ty rz + cy); u = clamp(tx rz), v = clamp(ty rz); rz = 1/tz
        f8 vt[3];
        vt[0] = gmx * fxr + select8(b.u_free, v_u * b.rz, splat8(0.f));
        vt[1] = gmy * fyr + select8(b.v_free, v_v * b.rz, splat8(0.f));
        v_rz += gmx * v.fx * b.t[0] + gmy * v.fy * b.t[1] +
                select8(b.u_free, v_u * b.t[0], splat8(0.f)) +
                select8(b.v_free, v_v * b.t[1], splat8(0.f));
        vt[2] = gz - v_rz * b.rz * b.rz;
        // culled Gaussians get no gradient (their intermediates may be inf or NaN)
        for (int i = 0; i < 3; ++i) {
          vt[i] = select8(vis, vt[i], splat8(0.f));
          vs[i] = select8(vis, vs[i], splat8(0.f));
          for (int k = 0; k < 3; ++k) {
            vR[i][k] = select8(vis, vR[i][k], splat8(0.f));
            vRq[i][k] = select8(vis, vRq[i][k], splat8(0.f));
          }
        }
        // t = R m + tv
        f8 vm[3];
        for (int a = 0; a < 3; ++a) {
          vm[a] = v.R[0][a] * vt[0] + v.R[1][a] * vt[1] + v.R[2][a] * vt[2];
          for (int i = 0; i < 3; ++i) lane_acc[3 * i + a] += vR[i][a] + vt[i] * b.m[a];
          lane_acc[9 + a] += vt[a];
        }
        for (int j = 0; j < 3; ++j) scatter(vs[j] * b.s[j], v_log_scales, 3, i0, cnt, j);
        // rotation of the unit quaternion -> (w,x,y,z), then through q/|q|: (I - q q^T) g / |q|
        const f8 w = b.q[0], x = b.q[1], y = b.q[2], z = b.q[3];
        const f8(&g)[3][3] = vRq;
        f8 gq[4];
        gq[0] = 2.f * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] +
                       x * g[2][1]);
        gq[1] = 2.f * (y * g[0][1] + z * g[0][2] + y * g[1][0] - 2.f * x * g[1][1] - w * g[1][2] +
                       z * g[2][0] + w * g[2][1] - 2.f * x * g[2][2]);
        gq[2] = 2.f * (-2.f * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] +
                       z * g[1][2] - w * g[2][0] + z * g[2][1] - 2.f * y * g[2][2]);
        gq[3] = 2.f * (-2.f * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] -
                       2.f * z * g[1][1] + y * g[1][2] + x * g[2][0] + y * g[2][1]);
        const f8 dot = gq[0] * w + gq[1] * x + gq[2] * y + gq[3] * z;
        const f8 qinv = select8(b.qnorm > splat8(0.f), splat8(1.f) / b.qnorm, splat8(0.f));
        for (int k = 0; k < 4; ++k)
          scatter((gq[k] - dot * b.q[k]) * qinv, v_quats, 4, i0, cnt, k);
        if (sh.sh) {  // colour of the direction m - campos
          const f8 dir[3] = {b.m[0] - v.campos[0], b.m[1] - v.campos[1], b.m[2] - v.campos[2]};
          f8 vdir[3] = {splat8(0.f), splat8(0.f), splat8(0.f)};
          sh_backward8(sh.degree, sh.K, sh.C, cnt, sh_dirs(dir), sh.sh + i0 * sh_row,
                       colors + i0 * sh.C, v_colors + i0 * sh.C, v_sh + i0 * sh_row, vdir);
          for (int a = 0; a < 3; ++a) {
            vm[a] += vdir[a];
            lane_acc[12 + a] += vdir[a];
          }
        }
        for (int a = 0; a < 3; ++a) scatter(vm[a], v_means, 3, i0, cnt, a);
      }
      for (int k = 0; k < kAcc; ++k)
        for (int j = 0; j < kLanes; ++j) acc[k] += lane_acc[k][j];
    }
  }
  if (!v_viewmat) return;
  double g[kAcc] = {0};
  for (int64_t c = 0; c < n_chunks; ++c)
    for (int k = 0; k < kAcc; ++k) g[k] += acc_view[(size_t)kAcc * c + k];
  // dirs = m - campos, campos = -R^T tv: dL/dcampos = -sum dL/ddir
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const double v_campos_b = -g[12 + b];
      g[3 * a + b] -= v.tv[a] * v_campos_b;
      g[9 + a] -= v.R[a][b] * v_campos_b;
    }
  for (int k = 0; k < 16; ++k) v_viewmat[k] = 0.f;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) v_viewmat[4 * a + b] = (float)g[3 * a + b];
    v_viewmat[4 * a + 3] = (float)g[9 + a];
  }
}

}  // namespace splat
