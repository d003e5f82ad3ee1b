"""One image of a prepared dataset and its camera (shared/FORMATS.md, section 1).

Poses are stored as nerfstudio does: camera-to-world with OpenGL axes (x right, y up, z back).
The rasterizer takes world-to-camera with OpenCV axes (x right, y down, z forward); `viewmat()`
converts. Intrinsics follow the nerfstudio pixel convention: pixel (i, j) is centred at
(i + 0.5, j + 0.5), so a centred principal point is (w/2, h/2).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MODALITIES = ("rgb", "thermal")
SPLITS = ("train", "test")
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # flips y and z; its own inverse


def c2w_opencv_to_opengl(c2w_cv: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world with OpenCV camera axes -> OpenGL camera axes (float64)."""
    return np.asarray(c2w_cv, np.float64) @ GL_FROM_CV


def viewmat_from_c2w_opengl(c2w_gl: np.ndarray) -> np.ndarray:
    """(4, 4) OpenGL camera-to-world -> (4, 4) float32 OpenCV world-to-camera.

    Inverted in closed form (R^T, -R^T t) in float64 before the cast, so the result is as
    rigid as the input.
    """
    c2w_cv = np.asarray(c2w_gl, np.float64) @ GL_FROM_CV
    rot_t = c2w_cv[:3, :3].T
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rot_t, -rot_t @ c2w_cv[:3, 3]
    return w2c.astype(np.float32)


@dataclass(frozen=True)
class Distortion:
    """OPENCV lens model of the image as stored (before undistortion on load)."""

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float
    k2: float
    p1: float
    p2: float

    def coefficients(self) -> np.ndarray:
        return np.array([self.k1, self.k2, self.p1, self.p2], np.float64)


@dataclass(frozen=True)
class Frame:
    """A frame of a prepared dataset. Intrinsics are pinhole ones for the image as loaded
    (after undistortion); `distortion` keeps the stored lens model when there was one."""

    file_path: str
    modality: str            # 'rgb' | 'thermal'
    camera: str              # physical camera name: cam0, cam1, ...
    time: float              # normalised capture time in [0, 1]
    timestamp_s: float | None
    c2w: np.ndarray          # (4, 4) float64 camera-to-world, OpenGL axes, as stored
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    split: str = "train"     # 'train' | 'test'
    distortion: Distortion | None = None
    mask_path: str | None = None   # optional object-label image (8-bit PNG, 0 = no object)

    def viewmat(self) -> np.ndarray:
        """(4, 4) float32 world-to-camera in OpenCV axes (what the rasterizer takes)."""
        return viewmat_from_c2w_opengl(self.c2w)

    def c2w_opencv(self) -> np.ndarray:
        """(4, 4) float64 camera-to-world in OpenCV axes."""
        return self.c2w @ GL_FROM_CV

    def intrinsics_matrix(self) -> np.ndarray:
        """K (3, 3) float64 in the nerfstudio pixel convention (pixel centres at +0.5)."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])
