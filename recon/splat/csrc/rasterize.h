// Tile-based front-to-back compositing of projected 2D Gaussians and its analytic VJP.
#pragma once
#include <cstdint>
#include <vector>

namespace splat {

struct RasterScene {
  int64_t n;
  int channels;
  int width, height;
  const float* means2d;    // (N,2) pixel coordinates, pixel centres at (x+0.5, y+0.5)
  const float* conics;     // (N,3) a,b,c of [[a,b],[b,c]] = inverse 2D covariance
  const float* colors;     // (N,C)
  const float* opacities;  // (N)
  const float* depths;     // (N) sort key and depth output
  const int32_t* radii;    // (N) 0 = culled by the projection
};

// Gaussian-tile lists, depth-sorted within each tile (what the backward re-walks).
struct Binning {
  int tiles_x = 0, tiles_y = 0;
  std::vector<int64_t> offsets;  // (tiles+1) into ids
  std::vector<int32_t> ids;      // Gaussian index of each (tile, Gaussian) pair
  std::vector<int32_t> boxes;    // (N,4) pixel box x0,x1,y0,y1 (inclusive); x0 > x1 when unused
};

// Non-owning view of a Binning (what the backward receives back from Python).
struct BinView {
  int tiles_x, tiles_y;
  const int64_t* offsets;
  const int32_t* ids;
  const int32_t* boxes;
};

inline BinView view_of(const Binning& b) {
  return {b.tiles_x, b.tiles_y, b.offsets.data(), b.ids.data(), b.boxes.data()};
}

// Throws std::length_error when the pairs would exceed max_pairs (bounded memory).
void bin_gaussians(const RasterScene& s, int64_t max_pairs, int threads, Binning& bins);

// Outputs: image (H,W,C) = sum_i w_i c_i, alpha (H,W) = 1 - T_final, depth (H,W) = sum_i w_i z_i
// (not normalised), final_T (H,W), last (H,W) = position in its tile list of each pixel's last
// contributor (-1 for none).
void rasterize_forward(const RasterScene& s, const BinView& bins, float* image, float* alpha,
                       float* depth, float* final_T, int32_t* last, int threads);

// v_image (H,W,C), v_alpha (H,W), v_depth (H,W) -> v_means2d (N,2), v_conics (N,3),
// v_colors (N,C), v_opacities (N), v_depths (N).
void rasterize_backward(const RasterScene& s, const BinView& bins, const float* final_T,
                        const int32_t* last, const float* v_image, const float* v_alpha,
                        const float* v_depth, float* v_means2d, float* v_conics, float* v_colors,
                        float* v_opacities, float* v_depths, int threads);

}  // namespace splat
