"""Renders of a run, stored like the ground truth so `recon eval` can compare them.

A run writes the render of test frame F to `RUN_DIR/renders/<F.file_path>` with the same
encoding as the dataset: RGB as 8-bit PNG, thermal as 16-bit PNG counts of thermal_scale_k
kelvin. Training code should call `write_render`; `read_render` checks what it reads.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from recon.data import Frame
from recon.data.images import check_header, read_raw

RENDERS = "renders"


class RenderError(ValueError):
    """A render is missing or does not match its ground-truth frame."""


def render_path(run_dir: str | Path, frame: Frame) -> Path:
    return Path(run_dir) / RENDERS / frame.file_path


def encode_render(image: np.ndarray, modality: str, thermal_scale_k: float | None) -> np.ndarray:
    """RGB float (H, W, 3) in [0, 1] -> uint8; thermal kelvin (H, W) -> uint16 counts (>= 1)."""
    image = np.asarray(image, np.float64)
    if modality == "rgb":
        return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)
    return np.clip(np.round(image / thermal_scale_k), 1, 65535).astype(np.uint16)


def write_render(run_dir: str | Path, frame: Frame, image: np.ndarray,
                 thermal_scale_k: float | None = None) -> Path:
    """Store one render (RGB float in [0, 1] or thermal kelvin) where `recon eval` looks."""
    return write_render_pixels(run_dir, frame, encode_render(image, frame.modality, thermal_scale_k))


def write_render_pixels(run_dir: str | Path, frame: Frame, pixels: np.ndarray) -> Path:
    """Store already-encoded render pixels (uint8 RGB or uint16 counts) where `recon eval` looks."""
    path = render_path(run_dir, frame).with_suffix(".png")
    expected = (frame.height, frame.width)
    if pixels.shape[:2] != expected:
        raise RenderError(f"{path}: render is {pixels.shape[1]}x{pixels.shape[0]}, frame is "
                          f"{frame.width}x{frame.height}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if pixels.ndim == 3:
        pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    cv2.imwrite(str(path), pixels)
    return path


def find_render(run_dir: str | Path, frame: Frame) -> Path | None:
    """The render file of `frame` (a JPEG ground truth is rendered as PNG), None if absent."""
    path = render_path(run_dir, frame)
    for candidate in (path, path.with_suffix(".png")):
        if candidate.is_file():
            return candidate
    return None


def read_render(run_dir: str | Path, frame: Frame) -> np.ndarray:
    """Stored pixels of the render of `frame`: uint8 (H, W, 3) or uint16 (H, W)."""
    path = find_render(run_dir, frame)
    if path is None:
        raise RenderError(f"{render_path(run_dir, frame)}: render missing for frame {frame.file_path}")
    try:
        check_header(path, frame.modality, frame.width, frame.height)
    except ValueError as e:
        raise RenderError(str(e)) from None
    return read_raw(path)
