// Loop shape (measured fastest on these CPUs, docs/rasterizer.md): per tile, Gaussians outer in
// depth order, pixels inner as strips of kStripLanes (a whole tile row with AVX-512, else 8).
// Each Gaussian only visits the strips of its own opacity-aware pixel box, so small Gaussians
// cost a few strips instead of the whole tile.
#include "rasterize.h"

#include <omp.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>

#include "common.h"

namespace splat {
namespace {

constexpr int kTilePixels = kTile * kTile;

const fs kLaneOffset = [] {  // pixel-centre offsets of a strip's lanes
  fs v;
  for (int l = 0; l < kStripLanes; ++l) v[l] = l + 0.5f;
  return v;
}();

uint32_t sort_key(float z) {
  uint32_t u;
  std::memcpy(&u, &z, 4);
  return (u & 0x80000000u) ? ~u : (u | 0x80000000u);  // order-preserving for all floats
}

// Stable LSD radix sort of idx by key (11-bit digits, 3 passes).
void radix_sort(std::vector<uint32_t>& key, std::vector<int32_t>& idx) {
  const size_t n = key.size();
  std::vector<uint32_t> key2(n);
  std::vector<int32_t> idx2(n);
  for (int shift = 0; shift < 32; shift += 11) {
    size_t count[2049] = {0};
    for (size_t i = 0; i < n; ++i) ++count[((key[i] >> shift) & 2047u) + 1];
    for (int b = 0; b < 2048; ++b) count[b + 1] += count[b];
    for (size_t i = 0; i < n; ++i) {
      const size_t pos = count[(key[i] >> shift) & 2047u]++;
      key2[pos] = key[i];
      idx2[pos] = idx[i];
    }
    key.swap(key2);
    idx.swap(idx2);
  }
}

struct TileBox {
  int row0, row1;      // tile-local rows, inclusive
  int strip0, strip1;  // strips of 8 lanes, inclusive
};

inline TileBox tile_box(const int32_t* box, int px0, int py0) {
  TileBox t;
  t.row0 = std::max(box[2], py0) - py0;
  t.row1 = std::min(box[3], py0 + kTile - 1) - py0;
  t.strip0 = (std::max(box[0], px0) - px0) / kStripLanes;
  t.strip1 = (std::min(box[1], px0 + kTile - 1) - px0) / kStripLanes;
  return t;
}

// Tiles a pixel box (x0,x1,y0,y1 inclusive; x1 < x0 when unused) overlaps: its pairs in the bins.
inline int64_t box_tiles(const int32_t* box) {
  if (box[1] < box[0] || box[3] < box[2]) return 0;
  return (int64_t)(box[1] / kTile - box[0] / kTile + 1) * (box[3] / kTile - box[2] / kTile + 1);
}

// Bit j (row-major over the tiles of Gaussian g's pixel box) set when g reaches a pixel centre of
// that tile (q <= r2, see reach_r2). A box reports the corner tiles of a tilted or round footprint
// too, and each listed pair costs a visit of its strips in the forward and the backward (a trained
// model's footprints are long and tilted: 15 % fewer pairs, a third less compositing at 640x480).
// Per row of tiles, the footprint's x-range over that row's pixel-centre band: with
// q = a (dx + b dy / a)^2 + (det / a) dy^2, the left edge -b dy / a - sqrt((r2 - det dy^2 / a) / a)
// is convex in dy, so its minimum over the band is at the ellipse's leftmost point (dy = b ex / c)
// clamped to the band; the right edge mirrors it. Only a box spanning several tiles both ways can
// miss one (an ellipse meets every tile of a one-row or one-column box); boxes of more than 64
// tiles keep every tile.
__attribute__((noinline)) uint64_t reached_tiles(const RasterScene& s, int64_t g, const int32_t* box,
                                                 double r2) {
  const float a = s.conics[3 * g], b = s.conics[3 * g + 1], c = s.conics[3 * g + 2];
  // A footprint that is round or axis-aligned (correlation of its axes below 0.5) misses only
  // corner tiles where its strips stop before their exp (power_cutoffs): cheaper than this test.
  if (b * b < 0.25f * a * c) return ~0ull;
  const int tx0 = box[0] / kTile, tx1 = box[1] / kTile, ty0 = box[2] / kTile, ty1 = box[3] / kTile;
  const int bw = tx1 - tx0 + 1, bh = ty1 - ty0 + 1;
  if (bw == 1 || bh == 1 || bw * bh > 64) return ~0ull;
  // double, as gaussian_bbox: a needle's det = ac - b^2 cancels almost entirely
  const double mx = s.means2d[2 * g], my = s.means2d[2 * g + 1];
  const double det = (double)a * c - (double)b * b, inv_a = 1.0 / a;
  const double ey = std::sqrt(r2 * a / det), ex = std::sqrt(r2 * c / det);
  const double slope = -b * inv_a, beta = det * inv_a, dy_left = b * ex / c;
  const auto edge = [&](double dy, double side) {
    return mx + slope * dy + side * std::sqrt(std::max(0.0, (r2 - beta * dy * dy) * inv_a));
  };
  uint64_t mask = 0;
  for (int ty = ty0, j = 0; ty <= ty1; ++ty) {
    const double lo = std::max(std::max(box[2], ty * kTile) + 0.5 - my, -ey);
    const double hi = std::min(std::min(box[3], ty * kTile + kTile - 1) + 0.5 - my, ey);
    const double left = edge(std::clamp(dy_left, std::min(lo, hi), hi), -1.0);
    const double right = edge(std::clamp(-dy_left, std::min(lo, hi), hi), 1.0);
    for (int tx = tx0; tx <= tx1; ++tx, ++j)
      if (tx * kTile + kTile - 0.5 >= left && tx * kTile + 0.5 <= right) mask |= 1ull << j;
  }
  return mask;
}

inline bool listed(uint64_t reach, int j) { return reach == ~0ull || ((reach >> j) & 1u); }

// Per Gaussian, -reach_r2 / 2: the power (-q/2) below which it cannot reach alpha >= 1/255
// (vectorised in float; the margin dwarfs its rounding): a strip with every lane below it is
// skipped before its exp.
std::vector<float> power_cutoffs(const RasterScene& s, int threads) {
  std::vector<float> cut((s.n + kLanes - 1) / kLanes * kLanes);
#pragma omp parallel for num_threads(threads) schedule(static, 256)
  for (int64_t i = 0; i < s.n; i += kLanes) {
    f8 o;
    for (int l = 0; l < kLanes; ++l) o[l] = i + l < s.n ? s.opacities[i + l] : 1.f;
    const f8 cv = splat8(-(float)kReachScale) * log8(max8(o * splat8(255.f), splat8(1.f))) -
                  splat8((float)(0.5 * kReachPad));
    std::memcpy(cut.data() + i, &cv, 32);
  }
  return cut;
}

struct GaussianParams {
  float mx, my, a, b, c, o, z;
};

// A tile's list visits Gaussians scattered over memory, and each visit's strips wait on its
// parameters: the loops ask for the entry kAhead places on (8 beat 16; docs/rasterizer.md,
// "Prefetch and per-channel builds").
constexpr int kAhead = 8;
inline void prefetch_gaussian(const RasterScene& s, const BinView& bins, const float* cut, int32_t g) {
  __builtin_prefetch(s.means2d + 2 * (int64_t)g);
  __builtin_prefetch(s.conics + 3 * (int64_t)g);
  __builtin_prefetch(s.conics + 3 * (int64_t)g + 2);
  __builtin_prefetch(s.opacities + g);
  __builtin_prefetch(s.depths + g);
  __builtin_prefetch(s.colors + (int64_t)g * s.channels);
  __builtin_prefetch(bins.boxes + 4 * (int64_t)g);
  __builtin_prefetch(cut + g);
}

inline GaussianParams load_gaussian(const RasterScene& s, int32_t g) {
  return {s.means2d[2 * g], s.means2d[2 * g + 1], s.conics[3 * g], s.conics[3 * g + 1],
          s.conics[3 * g + 2], s.opacities[g], s.depths[g]};
}

// power = -q/2 of the pixel strip starting at pixel column x (lanes x..x+kStripLanes-1) in row y.
inline fs strip_power(const GaussianParams& p, int x, int y, fs& dx, float& dy) {
  dx = kLaneOffset + splats((float)x) - splats(p.mx);
  dy = (float)y + 0.5f - p.my;
  return splats(-0.5f) * (splats(p.a) * dx * dx + splats(p.c * dy * dy)) -
         splats(p.b * dy) * dx;
}

}  // namespace

void bin_gaussians(const RasterScene& s, int64_t max_pairs, int threads, Binning& bins) {
  const int64_t n = s.n;
  bins.tiles_x = (s.width + kTile - 1) / kTile;
  bins.tiles_y = (s.height + kTile - 1) / kTile;
  const int64_t n_tiles = (int64_t)bins.tiles_x * bins.tiles_y;
  bins.boxes.assign(4 * n, 0);
  std::vector<uint8_t> visible(n, 0);  // 0: culled, 1: every tile of its box, kMasked: reach[i]
  constexpr uint8_t kMasked = 2;
  constexpr int32_t kMaskedBit = INT32_MIN;  // on order[k]: the passes below need no load to know
  const std::unique_ptr<uint64_t[]> reach(new uint64_t[n]);  // set where visible[i] == kMasked
#pragma omp parallel for num_threads(threads) schedule(static, 2048)
  for (int64_t i = 0; i < n; ++i) {
    int32_t* box = bins.boxes.data() + 4 * i;
    box[0] = 0;
    box[1] = -1;
    box[2] = 0;
    box[3] = -1;
    if (s.radii[i] <= 0) continue;
    double r2;
    visible[i] = gaussian_bbox(s.means2d[2 * i], s.means2d[2 * i + 1], s.conics[3 * i],
                               s.conics[3 * i + 1], s.conics[3 * i + 2], s.opacities[i],
                               s.width, s.height, box, r2);
    if (!visible[i]) {
      box[1] = box[3] = -1;
    } else {
      const uint64_t mask = reached_tiles(s, i, box, r2);
      if (mask != ~0ull) {  // rare on a dense scene of small round Gaussians: a flag, not a load
        reach[i] = mask;
        visible[i] = kMasked;
      }
    }
  }
  std::vector<int32_t> order;
  std::vector<uint32_t> keys;
  order.reserve(n);
  keys.reserve(n);
  for (int64_t i = 0; i < n; ++i)
    if (visible[i]) {
      order.push_back((int32_t)i | (visible[i] == kMasked ? kMaskedBit : 0));
      keys.push_back(sort_key(s.depths[i]));
    }
  radix_sort(keys, order);  // stable: equal depths keep index order
  const int64_t m = (int64_t)order.size();
  const int nt = std::max(1, threads);
  // Chunk c of the sorted list counts its pairs per tile; chunks fill in order, so every
  // tile list stays depth-sorted without a per-tile sort. More chunks than threads, handed out
  // dynamically, so a thread preempted by another process does not stall the whole pass.
  const int nc = (int)std::max<int64_t>(1, std::min<int64_t>(4 * nt, m / 256 + 1));
  std::vector<int64_t> counts((size_t)nc * n_tiles, 0);
  std::vector<int64_t> chunk_pairs(nc, 0);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 1)
  for (int c = 0; c < nc; ++c) {
    const int64_t lo = m * c / nc, hi = m * (c + 1) / nc;
    int64_t* cnt = counts.data() + (size_t)c * n_tiles;
    int64_t total = 0;
    for (int64_t k = lo; k < hi; ++k) {
      const int32_t g = order[k] & ~kMaskedBit;
      const int32_t* box = bins.boxes.data() + 4 * (int64_t)g;
      const int tx0 = box[0] / kTile, tx1 = box[1] / kTile;
      const int ty0 = box[2] / kTile, ty1 = box[3] / kTile;
      const uint64_t tiles = (order[k] & kMaskedBit) ? reach[g] : ~0ull;
      for (int ty = ty0, j = 0; ty <= ty1; ++ty)
        for (int tx = tx0; tx <= tx1; ++tx, ++j)
          if (listed(tiles, j)) {
            ++cnt[(int64_t)ty * bins.tiles_x + tx];
            ++total;
          }
    }
    chunk_pairs[c] = total;
  }
  int64_t pairs = 0;
  for (int c = 0; c < nc; ++c) pairs += chunk_pairs[c];
  if (pairs > max_pairs)
    throw std::length_error("rasterization: " + std::to_string(pairs) +
                            " Gaussian-tile intersections exceed the limit of " +
                            std::to_string(max_pairs) +
                            " (huge Gaussians on a large image); lower the resolution or "
                            "raise max_tile_pairs");
  bins.offsets.assign(n_tiles + 1, 0);
  // start[c][t]: where chunk c writes in tile t
  std::vector<int64_t>& start = counts;
  int64_t run = 0;
  for (int64_t t = 0; t < n_tiles; ++t) {
    bins.offsets[t] = run;
    for (int c = 0; c < nc; ++c) {
      const int64_t k = counts[(size_t)c * n_tiles + t];
      start[(size_t)c * n_tiles + t] = run;
      run += k;
    }
  }
  bins.offsets[n_tiles] = run;
  bins.ids.resize(pairs);
#pragma omp parallel for num_threads(nt) schedule(dynamic, 1)
  for (int c = 0; c < nc; ++c) {
    const int64_t lo = m * c / nc, hi = m * (c + 1) / nc;
    int64_t* pos = start.data() + (size_t)c * n_tiles;
    for (int64_t k = lo; k < hi; ++k) {
      const int32_t g = order[k] & ~kMaskedBit;
      const int32_t* box = bins.boxes.data() + 4 * (int64_t)g;
      const uint64_t tiles = (order[k] & kMaskedBit) ? reach[g] : ~0ull;
      for (int ty = box[2] / kTile, j = 0; ty <= box[3] / kTile; ++ty)
        for (int tx = box[0] / kTile; tx <= box[1] / kTile; ++tx, ++j)
          if (listed(tiles, j)) bins.ids[pos[(int64_t)ty * bins.tiles_x + tx]++] = g;
    }
  }
}

namespace {

// The compositing loops, compiled once per common channel count (kC; 0: any, s.channels): with C
// known the per-channel loops unroll (docs/rasterizer.md, "Prefetch and per-channel builds").
template <int kC>
void forward_impl(const RasterScene& s, const BinView& bins, float* image, float* alpha,
                  float* depth, float* final_T, int32_t* last, int threads) {
  const int C = kC > 0 ? kC : s.channels;
  const int64_t n_tiles = (int64_t)bins.tiles_x * bins.tiles_y;
  const std::vector<float> cut = power_cutoffs(s, std::max(1, threads));
#pragma omp parallel num_threads(std::max(1, threads))
  {
    alignas(64) float T[kTilePixels], D[kTilePixels];
    alignas(64) int32_t done[kTilePixels], lastk[kTilePixels];
    std::vector<fs> acc_buf((size_t)C * kTilePixels / kStripLanes);
    float* acc = reinterpret_cast<float*>(acc_buf.data());  // (C, 256)
#pragma omp for schedule(dynamic, 1)
    for (int64_t tile = 0; tile < n_tiles; ++tile) {
      const int px0 = (int)(tile % bins.tiles_x) * kTile, py0 = (int)(tile / bins.tiles_x) * kTile;
      int row_live[kTile];
      int live = 0;
      for (int r = 0; r < kTile; ++r) {
        row_live[r] = 0;
        for (int x = 0; x < kTile; ++x) {
          const int p = r * kTile + x;
          const bool inside = py0 + r < s.height && px0 + x < s.width;
          T[p] = 1.f;
          D[p] = 0.f;
          lastk[p] = -1;
          done[p] = inside ? 0 : -1;
          row_live[r] += inside;
        }
        live += row_live[r];
      }
      std::fill(acc, acc + (size_t)C * kTilePixels, 0.f);
      const int64_t k0 = bins.offsets[tile], k1 = bins.offsets[tile + 1];
      for (int64_t k = k0; k < k1 && live > 0; ++k) {
        if (k + kAhead < k1) prefetch_gaussian(s, bins, cut.data(), bins.ids[k + kAhead]);
        const int32_t g = bins.ids[k];
        const GaussianParams gp = load_gaussian(s, g);
        const TileBox tb = tile_box(bins.boxes + 4 * (int64_t)g, px0, py0);
        const float* col = s.colors + (int64_t)g * C;
        const is kv = splatis((int32_t)(k - k0));
        const fs cutv = splats(cut[g]);
        for (int r = tb.row0; r <= tb.row1; ++r) {
          if (row_live[r] == 0) continue;
          for (int st = tb.strip0; st <= tb.strip1; ++st) {
            const int p = r * kTile + st * kStripLanes;
            fs dx;
            float dy;
            const fs power = strip_power(gp, px0 + st * kStripLanes, py0 + r, dx, dy);
            if (!any(power >= cutv)) continue;
            fs a = splats(gp.o) * exp_nonpositive(power);
            a = a > splats(kAlphaMax) ? splats(kAlphaMax) : a;
            is dn;
            std::memcpy(&dn, done + p, sizeof(fs));
            is valid = (a >= splats(kAlphaMin)) & ~dn;
            if (!any(valid)) continue;
            fs t;
            std::memcpy(&t, T + p, sizeof(fs));
            const fs nt = t * (splats(1.f) - a);
            const is stop = valid & (nt < splats(kTransMin));
            valid &= ~stop;
            const fs w = select(valid, a * t, splats(0.f));
            for (int c = 0; c < C; ++c) {
              fs* ac = reinterpret_cast<fs*>(acc + (size_t)c * kTilePixels + p);
              *ac += w * splats(col[c]);
            }
            fs* dp = reinterpret_cast<fs*>(D + p);
            *dp += w * splats(gp.z);
            const fs t2 = select(valid, nt, t);
            std::memcpy(T + p, &t2, sizeof(fs));
            is lk;
            std::memcpy(&lk, lastk + p, sizeof(fs));
            lk = valid ? kv : lk;
            std::memcpy(lastk + p, &lk, sizeof(fs));
            if (any(stop)) {
              dn |= stop;
              std::memcpy(done + p, &dn, sizeof(fs));
              const int stopped = count(stop);
              row_live[r] -= stopped;
              live -= stopped;
            }
          }
        }
      }
      for (int r = 0; r < kTile && py0 + r < s.height; ++r) {
        for (int x = 0; x < kTile && px0 + x < s.width; ++x) {
          const int p = r * kTile + x;
          const int64_t pix = (int64_t)(py0 + r) * s.width + px0 + x;
          for (int c = 0; c < C; ++c) image[pix * C + c] = acc[(size_t)c * kTilePixels + p];
          alpha[pix] = 1.f - T[p];
          depth[pix] = D[p];
          final_T[pix] = T[p];
          last[pix] = lastk[p];
        }
      }
    }
  }
}

template <int kC>
void backward_impl(const RasterScene& s, const BinView& bins, const float* final_T,
                   const int32_t* last, const float* v_image, const float* v_alpha,
                   const float* v_depth, float* v_means2d, float* v_conics, float* v_colors,
                   float* v_opacities, float* v_depths, int threads) {
  const int C = kC > 0 ? kC : s.channels;
  const int stride = 7 + C;  // per-Gaussian gradient record: mx my a b c o z colour...
  const int64_t n = s.n;
  const int64_t n_tiles = (int64_t)bins.tiles_x * bins.tiles_y;
  const int nt = std::max(1, threads);
  const std::vector<float> cut = power_cutoffs(s, nt);
  // Training renders rarely take a loss on depth (autograd then hands in zeros): its terms are
  // then skipped (a trained 640x480 model: composite backward 37-39 -> 35-36 ms per render).
  // The values are the same either way.
  const bool depth_on = std::any_of(v_depth, v_depth + (int64_t)s.width * s.height,
                                    [](float v) { return v != 0.f; });
  // Deterministic: each (tile, Gaussian) pair writes its own gradient record (no atomics, no
  // per-thread sums), then every Gaussian sums its records in tile order. Tiles are still handed
  // out dynamically (robust to a core taken by another process), yet the gradients are the same
  // bits run after run and for any thread count: training is reproducible, and a test's result
  // does not depend on how the OS scheduled two threads (a moving-object test went 7.5-45 K
  // between identical runs with the old per-thread buffers). A Gaussian's pairs are the tiles of
  // its box, so its records sit together at first[g] + its tile's row-major place in the box.
  std::vector<int64_t> first(n + 1, 0);
  for (int64_t i = 0; i < n; ++i) first[i + 1] = first[i] + box_tiles(bins.boxes + 4 * i);
  // Only pairs some pixel received gradient through are written (most of a dense tile's list lies
  // behind every pixel's last contributor); `written` marks them.
  // Kept between calls (per calling thread): a fresh allocation of this size is fresh pages from
  // the kernel, and their page faults cost ~15% of a backward at 640x480.
  thread_local std::vector<float> recs;
  thread_local std::vector<uint8_t> written;
  if (recs.size() < (size_t)first[n] * stride) recs.resize((size_t)first[n] * stride);
  written.assign(first[n], 0);
  float* const rec = recs.data();   // thread_local: OpenMP's threads must use these pointers
  uint8_t* const wrote = written.data();
  const auto slot = [&](int32_t g, int tx, int ty) -> int64_t {
    const int32_t* box = bins.boxes + 4 * (int64_t)g;
    const int tx0 = box[0] / kTile, tx1 = box[1] / kTile, ty0 = box[2] / kTile;
    return first[g] + (int64_t)(ty - ty0) * (tx1 - tx0 + 1) + (tx - tx0);
  };
#pragma omp parallel num_threads(nt)
  {
    alignas(64) float T[kTilePixels], SD[kTilePixels], gD[kTilePixels], gAT[kTilePixels];
    alignas(64) int32_t lastk[kTilePixels];
    std::vector<fs> buf((size_t)2 * C * kTilePixels / kStripLanes + C);
    float* S = reinterpret_cast<float*>(buf.data());  // (C,256) colour composited behind
    float* gC = S + (size_t)C * kTilePixels;          // (C,256) dL/dimage
    fs* gcol = buf.data() + (size_t)2 * C * kTilePixels / kStripLanes;  // (C) lane accumulators
#pragma omp for schedule(dynamic, 1)
    for (int64_t tile = 0; tile < n_tiles; ++tile) {
      const int tx = (int)(tile % bins.tiles_x), ty = (int)(tile / bins.tiles_x);
      const int px0 = tx * kTile, py0 = ty * kTile;
      int kmax = -1;
      for (int r = 0; r < kTile; ++r) {
        for (int x = 0; x < kTile; ++x) {
          const int p = r * kTile + x;
          const bool inside = py0 + r < s.height && px0 + x < s.width;
          const int64_t pix = (int64_t)(py0 + r) * s.width + px0 + x;
          T[p] = inside ? final_T[pix] : 1.f;
          SD[p] = 0.f;
          gD[p] = inside ? v_depth[pix] : 0.f;
          gAT[p] = inside ? v_alpha[pix] * final_T[pix] : 0.f;
          lastk[p] = inside ? last[pix] : -1;
          kmax = std::max(kmax, lastk[p]);
          for (int c = 0; c < C; ++c) {
            S[(size_t)c * kTilePixels + p] = 0.f;
            gC[(size_t)c * kTilePixels + p] = inside ? v_image[pix * C + c] : 0.f;
          }
        }
      }
      const int64_t k0 = bins.offsets[tile];
      for (int64_t k = k0 + kmax; k >= k0; --k) {
        if (k - kAhead >= k0) {
          const int32_t ga = bins.ids[k - kAhead];
          prefetch_gaussian(s, bins, cut.data(), ga);
          __builtin_prefetch(first.data() + ga);
        }
        const int32_t g = bins.ids[k];
        const GaussianParams gp = load_gaussian(s, g);
        const TileBox tb = tile_box(bins.boxes + 4 * (int64_t)g, px0, py0);
        const float* col = s.colors + (int64_t)g * C;
        const is kv = splatis((int32_t)(k - k0));
        const fs cutv = splats(cut[g]);
        fs gmx = splats(0.f), gmy = gmx, ga = gmx, gb = gmx, gc = gmx, go = gmx, gz = gmx;
        for (int c = 0; c < C; ++c) gcol[c] = splats(0.f);
        bool touched = false;
        for (int r = tb.row0; r <= tb.row1; ++r) {
          for (int st = tb.strip0; st <= tb.strip1; ++st) {
            const int p = r * kTile + st * kStripLanes;
            is lk;
            std::memcpy(&lk, lastk + p, sizeof(fs));
            const is in_range = kv <= lk;
            if (!any(in_range)) continue;
            fs dx;
            float dy;
            const fs power = strip_power(gp, px0 + st * kStripLanes, py0 + r, dx, dy);
            if (!any(in_range & (power >= cutv))) continue;
            const fs G = exp_nonpositive(power);
            const fs ao = splats(gp.o) * G;
            const fs a = ao > splats(kAlphaMax) ? splats(kAlphaMax) : ao;
            const is valid = in_range & (a >= splats(kAlphaMin));
            if (!any(valid)) continue;
            touched = true;
            fs t;
            std::memcpy(&t, T + p, sizeof(fs));
            const fs inv = splats(1.f) / (splats(1.f) - a);
            const fs tb4 = t * inv;  // transmittance in front of this Gaussian
            const fs w = a * tb4;
            fs v_a = *reinterpret_cast<const fs*>(gAT + p) * inv;
            if (depth_on) {
              fs* sdp = reinterpret_cast<fs*>(SD + p);
              const fs gd = *reinterpret_cast<const fs*>(gD + p);
              v_a += gd * (splats(gp.z) * tb4 - *sdp * inv);
              gz += select(valid, w * gd, splats(0.f));
              *sdp = select(valid, *sdp + splats(gp.z) * w, *sdp);
            }
            for (int c = 0; c < C; ++c) {
              fs* sp = reinterpret_cast<fs*>(S + (size_t)c * kTilePixels + p);
              const fs gcv = *reinterpret_cast<const fs*>(gC + (size_t)c * kTilePixels + p);
              v_a += gcv * (splats(col[c]) * tb4 - *sp * inv);
              gcol[c] += select(valid, w * gcv, splats(0.f));
              *sp = select(valid, *sp + splats(col[c]) * w, *sp);
            }
            const fs t2 = select(valid, tb4, t);
            std::memcpy(T + p, &t2, sizeof(fs));
            // alpha = min(0.99, o G): no gradient through an active clamp
            const fs v_ao = select(valid & (ao <= splats(kAlphaMax)), v_a, splats(0.f));
            go += v_ao * G;
            const fs v_pow = v_ao * splats(gp.o) * G;
            const fs dyv = splats(dy);
            ga += v_pow * splats(-0.5f) * dx * dx;
            gb -= v_pow * dx * dyv;
            gc += v_pow * splats(-0.5f * dy * dy);
            gmx += v_pow * (splats(gp.a) * dx + splats(gp.b) * dyv);
            gmy += v_pow * (splats(gp.b) * dx + splats(gp.c) * dyv);
          }
        }
        if (!touched) continue;
        const int64_t r = slot(g, tx, ty);
        wrote[r] = 1;
        float* gr = rec + (size_t)r * stride;
        gr[0] = hsums(gmx);
        gr[1] = hsums(gmy);
        gr[2] = hsums(ga);
        gr[3] = hsums(gb);
        gr[4] = hsums(gc);
        gr[5] = hsums(go);
        gr[6] = hsums(gz);
        for (int c = 0; c < C; ++c) gr[7 + c] = hsums(gcol[c]);
      }
    }
    // the implicit barrier of the loop above has every record written
    std::vector<float> sum(stride);
#pragma omp for schedule(static, 2048)
    for (int64_t i = 0; i < n; ++i) {
      std::fill(sum.begin(), sum.end(), 0.f);
      for (int64_t r = first[i]; r < first[i + 1]; ++r) {
        if (!wrote[r]) continue;
        const float* gr = rec + (size_t)r * stride;
        for (int j = 0; j < stride; ++j) sum[j] += gr[j];
      }
      v_means2d[2 * i] = sum[0];
      v_means2d[2 * i + 1] = sum[1];
      v_conics[3 * i] = sum[2];
      v_conics[3 * i + 1] = sum[3];
      v_conics[3 * i + 2] = sum[4];
      v_opacities[i] = sum[5];
      v_depths[i] = sum[6];
      for (int c = 0; c < C; ++c) v_colors[i * C + c] = sum[7 + c];
    }
  }
}

}  // namespace

// Channel counts the product renders: RGB 3, thermal 1, each plus 2 or 3 distortion moments.
#define SPLAT_BY_CHANNELS(impl, ...)      \
  switch (s.channels) {                   \
    case 1: return impl<1>(__VA_ARGS__);  \
    case 3: return impl<3>(__VA_ARGS__);  \
    case 4: return impl<4>(__VA_ARGS__);  \
    case 5: return impl<5>(__VA_ARGS__);  \
    case 6: return impl<6>(__VA_ARGS__);  \
    default: return impl<0>(__VA_ARGS__); \
  }

void rasterize_forward(const RasterScene& s, const BinView& bins, float* image, float* alpha,
                       float* depth, float* final_T, int32_t* last, int threads) {
  SPLAT_BY_CHANNELS(forward_impl, s, bins, image, alpha, depth, final_T, last, threads)
}

void rasterize_backward(const RasterScene& s, const BinView& bins, const float* final_T,
                        const int32_t* last, const float* v_image, const float* v_alpha,
                        const float* v_depth, float* v_means2d, float* v_conics, float* v_colors,
                        float* v_opacities, float* v_depths, int threads) {
  SPLAT_BY_CHANNELS(backward_impl, s, bins, final_T, last, v_image, v_alpha, v_depth, v_means2d,
                    v_conics, v_colors, v_opacities, v_depths, threads)
}
#undef SPLAT_BY_CHANNELS

}  // namespace splat
