// Shared constants, the 8-lane float vector type and helpers of the CPU Gaussian rasterizer.
// GCC vector extensions (not intrinsics): they compile to AVX2 ymm code when built with
// -mavx2/-march=native and still build (as SSE pairs) anywhere else.
#pragma once
#include <cmath>
#include <cstdint>
#include <algorithm>

namespace splat {

constexpr float kAlphaMin = 1.0f / 255.0f;  // contributions below this are skipped (3DGS)
constexpr float kAlphaMax = 0.99f;          // alpha clamp (3DGS)
constexpr float kTransMin = 1e-4f;          // a pixel stops before T would fall below this
constexpr double kBlur = 0.3;               // low-pass added to the 2D covariance diagonal
constexpr int kTile = 16;                   // tile side in pixels; rows are 2 strips of 8 lanes
constexpr int kLanes = 8;

typedef float f8 __attribute__((vector_size(32)));
typedef int32_t i8 __attribute__((vector_size(32)));
// A strip of the rasterizer: a run of pixels of one row, one per lane. With AVX-512 a strip is a
// whole 16-pixel tile row (half the loop trips of two 8-lane strips, each as cheap on a core
// with 512-bit units); elsewhere 8 lanes. Projection and SH stay on f8 (8 Gaussians per step).
#ifdef __AVX512F__
constexpr int kStripLanes = 16;
typedef float fs __attribute__((vector_size(64)));
typedef int32_t is __attribute__((vector_size(64)));
#else
constexpr int kStripLanes = 8;
typedef f8 fs;
typedef i8 is;
#endif
template <class F> using IntOf = decltype(F{} < F{});  // the lane mask / int vector of F

inline f8 splat8(float x) { return f8{x, x, x, x, x, x, x, x}; }
inline i8 spliti8(int32_t x) { return i8{x, x, x, x, x, x, x, x}; }
inline f8 select8(i8 m, f8 a, f8 b) { return m ? a : b; }
inline fs splats(float x) { return fs{} + x; }
inline is splatis(int32_t x) { return is{} + x; }
template <class I, class F> inline F select(I m, F a, F b) { return m ? a : b; }
#ifdef __AVX__
#include <immintrin.h>
inline float hsum8(f8 v) {
  const __m128 lo = _mm256_castps256_ps128((__m256)v), hi = _mm256_extractf128_ps((__m256)v, 1);
  __m128 s = _mm_add_ps(lo, hi);
  s = _mm_add_ps(s, _mm_movehl_ps(s, s));
  s = _mm_add_ss(s, _mm_movehdup_ps(s));
  return _mm_cvtss_f32(s);
}
inline int mask8(i8 m) { return _mm256_movemask_ps((__m256)m); }
#else
inline float hsum8(f8 v) {
  float s = 0.f;
  for (int i = 0; i < kLanes; ++i) s += v[i];
  return s;
}
inline int mask8(i8 m) {
  int r = 0;
  for (int i = 0; i < kLanes; ++i) r |= (m[i] != 0) << i;
  return r;
}
#endif
#ifdef __AVX512F__
inline unsigned masks(is m) { return _mm512_cmplt_epi32_mask((__m512i)m, _mm512_setzero_si512()); }
inline float hsums(fs v) { return _mm512_reduce_add_ps((__m512)v); }
#else
inline unsigned masks(is m) { return (unsigned)mask8(m); }
inline float hsums(fs v) { return hsum8(v); }
#endif
inline bool any(is m) { return masks(m) != 0; }
inline int count(is m) { return __builtin_popcount(masks(m)); }

#ifdef __AVX__
inline f8 sqrt8(f8 x) { return (f8)_mm256_sqrt_ps((__m256)x); }
inline f8 floor8(f8 x) { return (f8)_mm256_floor_ps((__m256)x); }
inline f8 ceil8(f8 x) { return (f8)_mm256_ceil_ps((__m256)x); }
#else
inline f8 sqrt8(f8 x) {
  for (int i = 0; i < kLanes; ++i) x[i] = std::sqrt(x[i]);
  return x;
}
inline f8 floor8(f8 x) {
  for (int i = 0; i < kLanes; ++i) x[i] = std::floor(x[i]);
  return x;
}
inline f8 ceil8(f8 x) {
  for (int i = 0; i < kLanes; ++i) x[i] = std::ceil(x[i]);
  return x;
}
#endif
inline f8 min8(f8 a, f8 b) { return a < b ? a : b; }
inline f8 max8(f8 a, f8 b) { return a > b ? a : b; }

// 2^n e^r for x = n ln2 + r (n as int and as float, |r| <~ ln2): Cephes expf polynomial, ~1 ulp.
template <class F>
inline F exp_reduced(F x, IntOf<F> n, F nf) {
  const F r = x - nf * 0.693359375f + nf * 2.12194440e-4f;
  F p = F{} + 1.9875691500E-4f;
  p = p * r + 1.3981999507E-3f;
  p = p * r + 8.3334519073E-3f;
  p = p * r + 4.1665795894E-2f;
  p = p * r + 1.6666665459E-1f;
  p = p * r + 5.0000001201E-1f;
  p = p * r * r + r + 1.0f;
  const IntOf<F> e = (n + 127) << 23;
  F scale;
  __builtin_memcpy(&scale, &e, sizeof(scale));
  return p * scale;
}

// exp(x) for x <= 0 (the compositing hot loop); inputs below -87 return ~0.
template <class F>
inline F exp_nonpositive(F x) {
  x = x < -87.0f ? F{} - 87.0f : x;
  x = x > 0.0f ? F{} : x;
  // trunc(fx - 0.5) for fx <= 0 is ceil(fx - 0.5) = round-half-down: fine for range reduction
  const IntOf<F> n = __builtin_convertvector(x * 1.44269504088896341f - 0.5f, IntOf<F>);
  return exp_reduced(x, n, __builtin_convertvector(n, F));
}

// exp(x) for any x, clamped to [-87, 88] (e.g. log-scales).
inline f8 expf8(f8 x) {
  x = min8(max8(x, splat8(-87.0f)), splat8(88.0f));
  // round to nearest: adding 1.5 * 2^23 leaves no fraction bits (IEEE semantics, no fast-math)
  const f8 big = splat8(12582912.0f);
  const f8 nf = (x * splat8(1.44269504088896341f) + big) - big;
  return exp_reduced(x, __builtin_convertvector(nf, i8), nf);
}

// ln(x) for finite x > 0 (Cephes logf polynomial, ~1 ulp).
inline f8 log8(f8 x) {
  i8 bits;
  __builtin_memcpy(&bits, &x, sizeof(bits));
  f8 e = __builtin_convertvector(((bits >> 23) & spliti8(255)) - spliti8(126), f8);
  bits = (bits & spliti8(0x807fffff)) | spliti8(0x3f000000);  // mantissa in [0.5, 1)
  f8 m;
  __builtin_memcpy(&m, &bits, sizeof(m));
  const i8 low = m < splat8(0.707106781186547524f);
  e = select8(low, e - splat8(1.f), e);
  m = select8(low, m + m, m) - splat8(1.f);
  const f8 z = m * m;
  f8 y = splat8(7.0376836292E-2f);
  y = y * m + splat8(-1.1514610310E-1f);
  y = y * m + splat8(1.1676998740E-1f);
  y = y * m + splat8(-1.2420140846E-1f);
  y = y * m + splat8(1.4249322787E-1f);
  y = y * m + splat8(-1.6668057665E-1f);
  y = y * m + splat8(2.0000714765E-1f);
  y = y * m + splat8(-2.4999993993E-1f);
  y = y * m + splat8(3.3333331174E-1f);
  y = y * m * z + e * splat8(-2.12194440e-4f) - splat8(0.5f) * z;
  return m + y + e * splat8(0.693359375f);
}

// Squared Mahalanobis radius q within which a Gaussian of this opacity can reach alpha >= 1/255:
// o*exp(-q/2) >= 1/255  <=>  q <= 2 ln(255 o), widened to 2 ln(255 o) kReachScale + kReachPad so
// that every test built on it (pixel box, tile lists, strip cut-offs, the projection's culling)
// stays conservative against float rounding of the per-pixel evaluation.
constexpr double kReachScale = 1.001, kReachPad = 1e-3;
inline double reach_r2(float opacity) { return 2.0 * std::log(255.0 * (double)opacity) * kReachScale + kReachPad; }

// Pixel bounding box [x0,x1]x[y0,y1] (inclusive, clipped to the image) of the region where a
// Gaussian can reach alpha >= 1/255: o*exp(-q/2) >= 1/255  <=>  q <= 2 ln(255 o). Its extent
// along x is sqrt(r2 * Sigma_xx) (likewise y), Sigma = inverse conic. Pixel centres are at
// (x+0.5, y+0.5). Returns false when the region misses the image; r2 := reach_r2(opacity).
inline bool gaussian_bbox(float mx, float my, float ca, float cb, float cc, float opacity,
                          int width, int height, int32_t box[4], double& r2) {
  if (!(opacity >= kAlphaMin)) return false;
  const double det = (double)ca * cc - (double)cb * cb;
  if (!(det > 0.0)) return false;
  r2 = reach_r2(opacity);
  const double ex = std::sqrt(r2 * (double)cc / det);
  const double ey = std::sqrt(r2 * (double)ca / det);
  const double fx0 = std::ceil(mx - ex - 0.5), fx1 = std::floor(mx + ex - 0.5);
  const double fy0 = std::ceil(my - ey - 0.5), fy1 = std::floor(my + ey - 0.5);
  if (!(fx1 >= 0.0 && fx0 <= width - 1.0 && fy1 >= 0.0 && fy0 <= height - 1.0)) return false;
  if (!(fx0 <= fx1 && fy0 <= fy1)) return false;
  box[0] = (int32_t)std::max(0.0, fx0);
  box[1] = (int32_t)std::min(width - 1.0, fx1);
  box[2] = (int32_t)std::max(0.0, fy0);
  box[3] = (int32_t)std::min(height - 1.0, fy1);
  return true;
}

}  // namespace splat
