"""Procedural, non-repetitive surface textures (linear-light albedo) and their sampling.

Structure-from-motion on the simulated RGB frames needs texture that does not repeat: a regular
checkerboard floor registered 3 of 20 views with pycolmap, a noise floor 20 of 20 (see
shared/research/data_tools_facts.md). So every texture here is seeded noise at several scales
plus printed marks (letters, dots, strokes) drawn at random places.
"""
from __future__ import annotations

import string
from dataclasses import dataclass

import cv2
import numpy as np

_REMAP_COLS = 1024  # cv2.remap takes 2-D maps; long point lists are folded into rows of this width


@dataclass(frozen=True)
class Texture:
    """An (H, W, C) float32 image covering the surface at `texel_m` metres per texel."""

    image: np.ndarray
    texel_m: float

    def sample(self, uv_m: np.ndarray) -> np.ndarray:
        """Bilinear lookup at surface coordinates uv_m (N, 2) metres -> (N, C) float32.

        Coordinates outside the image wrap around (large textures; the repeat is never in view).
        """
        n = len(uv_m)
        if n == 0:
            return np.zeros((0, self.image.shape[2] if self.image.ndim == 3 else 1), np.float32)
        rows = -(-n // _REMAP_COLS)
        maps = np.zeros((2, rows * _REMAP_COLS), np.float32)
        maps[:, :n] = (uv_m / self.texel_m - 0.5).T  # texel i covers [i, i + 1) texel units
        out = cv2.remap(self.image, maps[0].reshape(rows, -1), maps[1].reshape(rows, -1),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out.reshape(rows * _REMAP_COLS, -1)[:n]


def fbm(h: int, w: int, rng: np.random.Generator, cell_px: float, octaves: int = 5,
        aspect: float = 1.0) -> np.ndarray:
    """Fractal value noise (H, W) float32 in [0, 1]; `aspect` > 1 stretches features along x."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        cy = max(cell_px / 2 ** k, 1.0)
        cx = cy * aspect
        grid = rng.random((int(h / cy) + 2, int(w / cx) + 2), dtype=np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.55
    out /= total
    lo, hi = np.percentile(out, [1, 99])
    return np.clip((out - lo) / (hi - lo + 1e-6), 0, 1)


def _lerp_colors(t: np.ndarray, a, b) -> np.ndarray:
    """(H, W) weights -> (H, W, 3) colours between a and b."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    return a + t[..., None] * (b - a)


def _print_marks(img: np.ndarray, rng: np.random.Generator, count: int, scale: float,
                 palette: list[tuple[float, float, float]]) -> None:
    """Draw random letters, dots and strokes in place on a linear float32 (H, W, 3) image.

    OpenCV draws text on 8-bit images only, so marks go to an 8-bit colour layer and an
    anti-aliased coverage layer that is then blended into the float image.
    """
    h, w = img.shape[:2]
    color_layer = np.zeros((h, w, 3), np.uint8)
    coverage = np.zeros((h, w), np.uint8)
    letters = list(string.ascii_letters + string.digits + "#%&@?")
    for _ in range(count):
        color = tuple(int(255 * c) for c in palette[rng.integers(len(palette))])
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        kind = rng.integers(3)
        if kind == 0:
            text = "".join(rng.choice(letters, size=int(rng.integers(1, 5))))
            font, size = int(rng.choice([0, 2, 3, 4])), scale * rng.uniform(0.6, 2.0)
            draw = lambda layer, ink: cv2.putText(layer, text, (x, y), font, size, ink,
                                                  max(1, int(scale * 2)), cv2.LINE_AA)
        elif kind == 1:
            radius = int(scale * rng.uniform(3, 14))
            draw = lambda layer, ink: cv2.circle(layer, (x, y), radius, ink, -1, cv2.LINE_AA)
        else:
            pts = (np.cumsum(rng.normal(0, scale * 12, size=(4, 2)), axis=0) + (x, y)).astype(np.int32)
            width = max(1, int(scale * rng.uniform(1, 4)))
            draw = lambda layer, ink: cv2.polylines(layer, [pts], False, ink, width, cv2.LINE_AA)
        draw(color_layer, color)
        draw(coverage, 255)
    alpha = coverage[..., None].astype(np.float32) / 255
    img *= 1 - alpha
    img += alpha * color_layer.astype(np.float32) / 255


def table_texture(rng: np.random.Generator, size_m=(1.2, 0.8), texel_m=0.0006) -> Texture:
    """Wood grain with a few printed sheets, stickers and pen marks lying on it."""
    w, h = int(size_m[0] / texel_m), int(size_m[1] / texel_m)
    grain = fbm(h, w, rng, cell_px=40, octaves=6, aspect=8.0)
    img = _lerp_colors(grain, (0.20, 0.09, 0.035), (0.52, 0.30, 0.14))
    img *= (0.8 + 0.4 * fbm(h, w, rng, cell_px=200, octaves=3))[..., None]
    for _ in range(5):  # sheets of paper / card with print on them
        cx, cy = rng.uniform(0.1, 0.9) * w, rng.uniform(0.1, 0.9) * h
        sw, sh = rng.uniform(0.08, 0.22) / texel_m, rng.uniform(0.06, 0.16) / texel_m
        box = cv2.boxPoints(((cx, cy), (sw, sh), rng.uniform(0, 180))).astype(np.int32)
        paper = tuple(float(c) for c in rng.uniform([0.55, 0.55, 0.5], [0.85, 0.85, 0.8]))
        cv2.fillPoly(img, [box], paper, cv2.LINE_AA)
    palette = [(0.02, 0.02, 0.02), (0.6, 0.05, 0.03), (0.03, 0.1, 0.5), (0.05, 0.35, 0.08),
               (0.75, 0.6, 0.05), (0.8, 0.8, 0.78)]
    _print_marks(img, rng, count=int(w * h / 7000), scale=1.0, palette=palette)
    img *= (0.85 + 0.3 * fbm(h, w, rng, cell_px=6, octaves=2))[..., None]
    return Texture(np.clip(img, 0.01, 0.95), texel_m)


def patterned_texture(rng: np.random.Generator, base, accent, size_px=(512, 512),
                      texel_m=0.0004, marks=250) -> Texture:
    """A coloured object surface: blotchy base colour, accent patches and printed marks."""
    h, w = size_px
    img = _lerp_colors(fbm(h, w, rng, cell_px=60), np.asarray(base) * 0.7, np.asarray(base) * 1.2)
    blobs = fbm(h, w, rng, cell_px=90, octaves=3) > 0.62
    img[blobs] = np.asarray(accent, np.float32)
    palette = [(0.02, 0.02, 0.02), (0.85, 0.85, 0.85), tuple(accent)]
    _print_marks(img, rng, count=marks, scale=0.7, palette=palette)
    img *= (0.85 + 0.3 * fbm(h, w, rng, cell_px=5, octaves=2))[..., None]
    return Texture(np.clip(img, 0.01, 0.95), texel_m)


def plain_texture(rng: np.random.Generator, color, contrast: float, size_px=(256, 256),
                  texel_m=0.01) -> Texture:
    """A low-contrast surface (walls, floor, water): colour times soft noise."""
    h, w = size_px
    noise = fbm(h, w, rng, cell_px=32, octaves=5)
    img = np.asarray(color, np.float32) * (1 - contrast + 2 * contrast * noise)[..., None]
    return Texture(np.clip(img, 0.005, 0.95).astype(np.float32), texel_m)

