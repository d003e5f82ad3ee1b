// EWA projection of 3D Gaussians to pixel-space 2D Gaussians (3DGS math), fused with their
// view-dependent SH colour, and the analytic VJP of both.
#pragma once
#include <cstdint>

namespace splat {

struct Camera {
  float viewmat[16];  // row-major world-to-camera, OpenCV axes
  float fx, fy, cx, cy;
  int width, height;
  float near_plane;
  // The image is the window at (win_x0, win_y0) of a full_width x full_height view (the whole
  // view: 0, 0, width, height). The Jacobian's clamp follows the full view's edges, so a window
  // renders exactly that part of the full render.
  int win_x0 = 0, win_y0 = 0, full_width = 0, full_height = 0;
  // Cull a Gaussian whose centre projects more than beside x the full view's width (height)
  // beyond its edges; < 0: off. The clamp above keeps such a Gaussian's small depth with the
  // edge's Jacobian, so a long one far to the side can cover the whole view.
  float beside = -1.f;
};

// Optional SH colour: sh (N,K,C) with K >= (degree+1)^2, evaluated for the direction camera ->
// Gaussian mean; sh == nullptr skips it.
struct ShInput {
  const float* sh = nullptr;
  int K = 0, C = 0, degree = 0;
};

// means (N,3), quats (N,4 wxyz, any norm), log_scales (N,3), opacities (N) ->
// means2d (N,2), conics (N,3: a,b,c of the inverse 2D covariance [[a,b],[b,c]]),
// depths (N, camera z), radii (N, 0 = culled), colors (N,C) when sh.sh is set (else unused).
void project_forward(int64_t n, const float* means, const float* quats, const float* log_scales,
                     const float* opacities, const Camera& cam, const ShInput& sh,
                     float* means2d, float* conics, float* depths, int32_t* radii,
                     float* colors, int threads);

// Gradients of means2d, conics, depths (and of colors (N,C) when sh.sh is set, given the
// forward's colors) -> means, quats, log_scales, viewmat (4x4) and sh (N,K,C).
void project_backward(int64_t n, const float* means, const float* quats, const float* log_scales,
                      const int32_t* radii, const Camera& cam, const ShInput& sh,
                      const float* colors, const float* v_means2d, const float* v_conics,
                      const float* v_depths, const float* v_colors, float* v_means,
                      float* v_quats, float* v_log_scales, float* v_viewmat, float* v_sh,
                      int threads);

}  // namespace splat
