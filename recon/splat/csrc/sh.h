// View-dependent colour from real spherical harmonics up to degree 3 (3DGS constants and
// convention: colour = max(sum_k sh_k Y_k(dir) + 0.5, 0)) and its VJP.
#pragma once
#include <cstdint>

namespace splat {

// sh (N,K,C) with K >= (degree+1)^2 (the extra coefficients are ignored), dirs (N,3) need not
// be unit length -> colors (N,C).
void sh_forward(int64_t n, int K, int C, int degree, const float* sh, const float* dirs,
                float* colors, int threads);

// v_colors (N,C) -> v_sh (N,K,C), v_dirs (N,3).
void sh_backward(int64_t n, int K, int C, int degree, const float* sh, const float* dirs,
                 const float* colors, const float* v_colors, float* v_sh, float* v_dirs,
                 int threads);

}  // namespace splat
