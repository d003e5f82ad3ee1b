"""The `rig calibrate` checkerboard as a simulated object: geometry, albedo and temperature of its
front face. A leaf module: the calibration world (rig/sim/calibration.py) stands it on a post, the
table-top scene (rig/sim/tabletop.py) lays a paper print of it behind its objects."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rig.sim.textures import Texture

PX_PER_SQUARE = 64


@dataclass(frozen=True)
class CheckerboardTarget:
    squares: tuple[int, int] = (9, 7)   # along the board's x and y; inner corners (8, 6)
    square_m: float = 0.016
    margin_m: float = 0.02
    thickness_m: float = 0.006
    hot_k: float = 273.15 + 45.0            # black squares
    cold_k: float = 273.15 + 28.0           # white squares and margin
    blur_m: float = 0.0015              # lateral heat conduction in the board

    @property
    def size_m(self) -> tuple[float, float]:
        return (self.squares[0] * self.square_m + 2 * self.margin_m,
                self.squares[1] * self.square_m + 2 * self.margin_m)

    @property
    def pattern_size(self) -> tuple[int, int]:
        """Inner corners (columns, rows): what cv2.findChessboardCorners takes."""
        return self.squares[0] - 1, self.squares[1] - 1

    def inner_corners_local(self) -> np.ndarray:
        """(N, 3) inner corners on the front face, row by row, board frame (centre origin)."""
        w, h = self.size_m
        i, j = np.meshgrid(np.arange(1, self.squares[0]), np.arange(1, self.squares[1]))
        x = -w / 2 + self.margin_m + i.ravel() * self.square_m
        y = -h / 2 + self.margin_m + j.ravel() * self.square_m
        return np.stack([x, y, np.full_like(x, self.thickness_m / 2)], axis=1)

    def face_textures(self) -> tuple[Texture, Texture]:
        """Albedo (H, W, 3) and kelvin (H, W, 1) of the front face; texel (0, 0) at its corner."""
        texel = self.square_m / PX_PER_SQUARE
        w, h = (int(round(s / texel)) for s in self.size_m)
        x = (np.arange(w) + 0.5) * texel - self.margin_m
        y = (np.arange(h) + 0.5) * texel - self.margin_m
        ci, cj = np.floor(x / self.square_m)[None, :], np.floor(y / self.square_m)[:, None]
        inside = (ci >= 0) & (ci < self.squares[0]) & (cj >= 0) & (cj < self.squares[1])
        black = (inside & ((ci + cj) % 2 == 0)).astype(np.float32)
        albedo = np.repeat((0.85 - 0.82 * black)[..., None], 3, axis=2)
        warm = cv2.GaussianBlur(black, (0, 0), self.blur_m / texel)
        kelvin = self.cold_k + (self.hot_k - self.cold_k) * warm
        return Texture(albedo, texel), Texture(kelvin[..., None].astype(np.float32), texel)
