// View-dependent colour from real spherical harmonics up to degree 3 (3DGS constants and
// convention: colour = max(sum_k sh_k Y_k(dir) + 0.5, 0)) and its VJP, for a block of up to
// 8 Gaussians (one per lane; the projection calls these per block, fused with its own pass).
#pragma once
#include "common.h"

namespace splat {

// A block's unit view directions (lanes) and 1/|dir| (0 for a zero direction, which leaves
// only the degree-0 term and gets no gradient).
struct ShDirs {
  f8 u[3];
  f8 inv_len;
};

ShDirs sh_dirs(const f8 dir[3]);

// sh: the block's rows of (N,K,C) with K >= (degree+1)^2 (extra coefficients ignored);
// colors: its rows of (N,C). Lanes j < cnt are Gaussians; the rest are not read or written.
void sh_forward8(int degree, int K, int C, int cnt, const ShDirs& d, const float* sh,
                 float* colors);

// v_colors (cnt,C) -> v_sh (cnt,K,C) (written, zero past the degree), v_dir (lanes, added to).
void sh_backward8(int degree, int K, int C, int cnt, const ShDirs& d, const float* sh,
                  const float* colors, const float* v_colors, float* v_sh, f8 v_dir[3]);

}  // namespace splat
