// EWA projection of 3D Gaussians to pixel-space 2D Gaussians (3DGS math) and its analytic VJP.
#pragma once
#include <cstdint>

namespace splat {

struct Camera {
  float viewmat[16];  // row-major world-to-camera, OpenCV axes
  float fx, fy, cx, cy;
  int width, height;
  float near_plane;
};

// means (N,3), quats (N,4 wxyz, any norm), log_scales (N,3), opacities (N) ->
// means2d (N,2), conics (N,3: a,b,c of the inverse 2D covariance [[a,b],[b,c]]),
// depths (N, camera z), radii (N, 0 = culled).
void project_forward(int64_t n, const float* means, const float* quats, const float* log_scales,
                     const float* opacities, const Camera& cam, float* means2d, float* conics,
                     float* depths, int32_t* radii, int threads);

// Gradients of means2d, conics, depths -> means, quats, log_scales, viewmat (4x4, may be null).
void project_backward(int64_t n, const float* means, const float* quats, const float* log_scales,
                      const int32_t* radii, const Camera& cam, const float* v_means2d,
                      const float* v_conics, const float* v_depths, float* v_means,
                      float* v_quats, float* v_log_scales, float* v_viewmat, int threads);

}  // namespace splat
