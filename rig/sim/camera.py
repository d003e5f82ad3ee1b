"""Pinhole cameras of the simulated rig: intrinsics, look-at poses, per-pixel rays.

Conventions (the same as the prepared-dataset contract, nerfstudio style):
- camera axes OpenCV: x right, y down, z forward; poses are 4x4 camera-to-world (c2w);
- pixel (col i, row j) covers [i, i+1) x [j, j+1) in image coordinates, so its centre is at
  (i + 0.5, j + 0.5) and a centred principal point is (W/2, H/2);
- a world point X projects to u = fx * x/z + cx, v = fy * y/z + cy with (x, y, z) = w2c X.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels of a `width` x `height` image."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float,
                 vfov_deg: float | None = None) -> "Intrinsics":
        """Centred pinhole from fields of view; square pixels when vfov_deg is None."""
        fx = width / 2 / np.tan(np.radians(hfov_deg) / 2)
        fy = fx if vfov_deg is None else height / 2 / np.tan(np.radians(vfov_deg) / 2)
        return cls(float(fx), float(fy), width / 2, height / 2, width, height)

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """The same lens and sensor sampled at another resolution."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)

    def matrix(self) -> np.ndarray:
        """K: (3, 3) float64."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, roll_rad: float = 0.0,
            up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """c2w (4, 4) float64 of an OpenCV camera at `eye` looking at `target` (world z is up)."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    x, y = c * x + s * y, -s * x + c * y
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w


def rotation(axis: str, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about a coordinate axis 'x', 'y' or 'z' (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


@lru_cache(maxsize=8)
def pixel_directions(fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                     ss: int) -> np.ndarray:
    """Camera-frame ray directions with z = 1 for an ss x ss grid of samples per pixel.

    Returns (height*ss, width*ss, 3) float32, read-only (cached: cameras repeat); sample (a, b)
    of pixel (i, j) sits at (i + (b + 0.5)/ss, j + (a + 0.5)/ss), so averaging ss x ss blocks
    gives a box-filtered pixel.
    """
    u = (np.arange(width * ss, dtype=np.float64) + 0.5) / ss
    v = (np.arange(height * ss, dtype=np.float64) + 0.5) / ss
    dirs = np.empty((height * ss, width * ss, 3), np.float32)
    dirs[..., 0] = ((u - cx) / fx)[None, :]
    dirs[..., 1] = ((v - cy) / fy)[:, None]
    dirs[..., 2] = 1.0
    dirs.flags.writeable = False
    return dirs


def box_downsample(samples: np.ndarray, ss: int) -> np.ndarray:
    """Average ss x ss blocks: (H*ss, W*ss, ...) -> (H, W, ...) float64."""
    if ss == 1:
        return samples.astype(np.float64)
    h, w = samples.shape[0] // ss, samples.shape[1] // ss
    blocks = samples.reshape(h, ss, w, ss, *samples.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64)
