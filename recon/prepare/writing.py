"""Dataset frames from the recovered poses: images (optionally downscaled), metric poses in the
dataset's OpenGL convention, intrinsics and lens models, thermal counts.

Lens models: a lens whose k1 k2 p1 p2 move no pixel by MIN_DISTORTION_PX or more is written as
PINHOLE (undistorting it would only resample the image); otherwise the OPENCV model is stored
and `recon.data` undistorts on load.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.data import Distortion, Frame, c2w_opencv_to_opengl
from recon.prepare.frames import Selected, Timeline
from rig.calibrate import Lens

THERMAL_SCALE_K = 0.01          # dataset counts: TemperatureLinear10mK (lossless for 10 / 100 mK input)
MIN_DISTORTION_PX = 0.25


def box_pixels(box, w: int, h: int) -> tuple[slice, slice]:
    """Rows and columns of a (x0, y0, x1, y1) box given as fractions of a w x h image."""
    x0, y0, x1, y1 = box
    return slice(int(y0 * h), int(np.ceil(y1 * h))), slice(int(x0 * w), int(np.ceil(x1 * w)))


def max_distortion_px(fx: float, fy: float, cx: float, cy: float, w: int, h: int, d: np.ndarray) -> float:
    """Largest displacement (px) the k1 k2 p1 p2 model applies at the image corners."""
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], np.float64)
    x, y = (corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy
    r2 = x * x + y * y
    radial = d[0] * r2 + d[1] * r2 * r2
    dx = x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x)
    dy = y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y
    return float(np.max(np.hypot(dx * fx, dy * fy)))


def dataset_intrinsics(lens: Lens, factor: int) -> tuple[tuple[float, ...], Distortion | None]:
    """(fx, fy, cx, cy) after downscaling by `factor`, and the lens model to store (None = pinhole)."""
    k = (lens.fx / factor, lens.fy / factor, lens.cx / factor, lens.cy / factor)
    if max_distortion_px(lens.fx, lens.fy, lens.cx, lens.cy, lens.width, lens.height,
                         lens.coefficients()) < MIN_DISTORTION_PX:
        return k, None
    return k, Distortion(*k, *(float(v) for v in lens.coefficients()))


def downscale_rgb(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    h, w = img.shape[:2]
    return cv2.resize(img, (w // f, h // f), interpolation=cv2.INTER_AREA)


def downscale_counts(counts: np.ndarray, f: int) -> np.ndarray:
    """uint16 counts averaged over f x f blocks; a block with any unmeasured (0) pixel is 0."""
    if f == 1:
        return counts
    h, w = counts.shape[0] // f * f, counts.shape[1] // f * f
    blocks = counts[:h, :w].reshape(h // f, f, w // f, f).astype(np.float64)
    out = np.round(blocks.mean(axis=(1, 3)))
    out[(blocks == 0).any(axis=(1, 3))] = 0
    return out.astype(np.uint16)


def thermal_counts(frame, box=None) -> np.ndarray:
    """A session thermal frame (rig.session.ThermalFrame) as dataset counts, 0 = no measurement
    (also inside `box`, e.g. the sync lamp, which is not part of the scene)."""
    kelvin = frame.kelvin()
    counts = np.clip(np.round(kelvin / THERMAL_SCALE_K), 0, 65535).astype(np.uint16)
    counts[~np.isfinite(kelvin) | (frame.counts == 0)] = 0
    if box is not None:
        counts[box_pixels(box, counts.shape[1], counts.shape[0])] = 0
    return counts


def thermal_range_k(frames: list[tuple[Frame, np.ndarray]]) -> tuple[float, float]:
    """[min, max] kelvin for normalising temperature: 0.1-99.9 percentiles of the measured
    thermal pixels, widened by 3 % of the span on each side."""
    counts = np.concatenate([px[px > 0] for fr, px in frames if fr.modality == "thermal"])
    lo, hi = np.percentile(counts, [0.1, 99.9]) * THERMAL_SCALE_K
    margin = 0.03 * (hi - lo)
    return round(float(lo - margin), 2), round(float(hi + margin), 2)


@dataclass
class Step:
    """One registered time step: the phone frame, its pose and lens, and its thermal partner's pose."""
    selected: Selected
    c2w_rgb: np.ndarray         # (4, 4) metres, OpenCV axes
    rgb_lens: Lens
    c2w_thermal: np.ndarray     # (4, 4) metres, OpenCV axes
    split: str


def dataset_frames(session, timeline: Timeline, steps: list[Step], thermal_lens: Lens, downscale: int,
                   box=None) -> list[tuple[Frame, np.ndarray]]:
    """(Frame, pixels) pairs, RGB then thermal for each step, named rgb|thermal/{step:06d}_cam0.png;
    `time` is normalised over the paired span of the session."""
    span = max(timeline.t1 - timeline.t0, 1e-9)
    k_th, dist_th = dataset_intrinsics(thermal_lens, downscale)
    out = []
    for i, st in enumerate(steps):
        pair = st.selected.pair
        rgb = downscale_rgb(st.selected.image, downscale)
        k, dist = dataset_intrinsics(st.rgb_lens, downscale)
        t = pair.rgb_s - timeline.t0
        out.append((Frame(f"rgb/{i:06d}_cam0.png", "rgb", "cam0", float(np.clip(t / span, 0, 1)), t,
                          c2w_opencv_to_opengl(st.c2w_rgb), *k, rgb.shape[1], rgb.shape[0], st.split, dist), rgb))
        counts = downscale_counts(thermal_counts(session.thermal_frame(pair.thermal_index), box), downscale)
        t = pair.thermal_s - timeline.t0
        out.append((Frame(f"thermal/{i:06d}_cam0.png", "thermal", "cam0", float(np.clip(t / span, 0, 1)), t,
                          c2w_opencv_to_opengl(st.c2w_thermal), *k_th, counts.shape[1], counts.shape[0], st.split,
                          dist_th), counts))
    return out
