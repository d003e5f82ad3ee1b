"""Write a prepared dataset in the exact layout of shared/FORMATS.md.

Used by `recon simulate` and by `recon prepare`. Images are written as they come (frames may be
a generator, so a long sequence never sits in memory), transforms.json last and atomically, so a
folder without transforms.json is visibly incomplete. Same inputs give the same bytes.
"""
from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from recon.data.frame import Frame
from recon.data.ply import write_points_ply

POINTS_FILE = "points3d.ply"


def _check_pixels(frame: Frame, pixels: np.ndarray) -> None:
    expected = ((frame.height, frame.width, 3), np.uint8) if frame.modality == "rgb" else \
        ((frame.height, frame.width), np.uint16)
    if pixels.shape != expected[0] or pixels.dtype != expected[1]:
        raise ValueError(f"{frame.file_path}: {frame.modality} pixels must be {expected[1].__name__} "
                         f"{expected[0]}, got {pixels.dtype} {pixels.shape}")
    if frame.modality == "thermal" and frame.file_path.lower().endswith((".jpg", ".jpeg")):
        raise ValueError(f"{frame.file_path}: thermal frames must be PNG (16-bit)")


def _write_image(path: Path, frame: Frame, pixels: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = pixels if frame.modality == "thermal" else cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if path.suffix.lower() in (".jpg", ".jpeg") else \
        [cv2.IMWRITE_PNG_COMPRESSION, 3]
    if not cv2.imwrite(str(path), data, params):
        raise OSError(f"{path}: could not write image")


def _write_mask(path: Path, labels: np.ndarray, frame: Frame) -> None:
    if labels.shape != (frame.height, frame.width) or labels.dtype != np.uint8:
        raise ValueError(f"{frame.file_path}: a mask must be uint8 {(frame.height, frame.width)}, "
                         f"got {labels.dtype} {labels.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), labels, [cv2.IMWRITE_PNG_COMPRESSION, 3]):
        raise OSError(f"{path}: could not write mask")


def frame_entry(frame: Frame) -> dict:
    """The transforms.json object of one frame."""
    entry = {"file_path": frame.file_path, "modality": frame.modality, "camera": frame.camera,
             "time": float(frame.time)}
    if frame.timestamp_s is not None:
        entry["timestamp_s"] = float(frame.timestamp_s)
    entry["transform_matrix"] = np.asarray(frame.c2w, np.float64).tolist()
    d = frame.distortion
    fx, fy, cx, cy = (d.fx, d.fy, d.cx, d.cy) if d else (frame.fx, frame.fy, frame.cx, frame.cy)
    entry.update({"fl_x": float(fx), "fl_y": float(fy), "cx": float(cx), "cy": float(cy),
                  "w": int(frame.width), "h": int(frame.height)})
    if d:
        entry.update({"k1": d.k1, "k2": d.k2, "p1": d.p1, "p2": d.p2})
    if frame.mask_path is not None:
        entry["mask_path"] = frame.mask_path
    return entry


def mask_path_of(frame: Frame) -> str:
    """Where a frame's object-label mask goes: masks/<modality>/<stem>.png."""
    return f"masks/{frame.modality}/{Path(frame.file_path).stem}.png"


def write_dataset(out_dir: str | Path, frames: Iterable[tuple[Frame, np.ndarray]],
                  thermal_scale_k: float | None = None,
                  thermal_range_k: tuple[float, float] | None = None,
                  points_xyz: np.ndarray | None = None, points_rgb: np.ndarray | None = None,
                  explicit_splits: bool = False, sidecars: dict[str, dict] | None = None,
                  mask_labels: dict[int, dict] | None = None) -> Path:
    """Write images, optional points3d.ply, JSON sidecars, then transforms.json; returns its path.

    frames: (Frame, pixels) pairs or (Frame, pixels, labels) triples; pixels are uint8 (H, W, 3)
    RGB or uint16 (H, W) thermal counts in `thermal_scale_k`; labels, uint8 (H, W) object ids,
    are written as the frame's mask (mask_path) and mask_labels {id: {"name", "moving"}} named
    in transforms.json. A frame's `distortion` (stored lens) makes the camera model OPENCV. With
    explicit_splits, train/test_filenames are written from `Frame.split`; otherwise readers
    apply the default rule (camera cam1 is test).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    entries, splits, distorted = [], {"train": [], "test": []}, False
    for frame, pixels, *labels in frames:
        _check_pixels(frame, pixels)
        _write_image(out / frame.file_path, frame, pixels)
        if labels and labels[0] is not None:
            frame = replace(frame, mask_path=mask_path_of(frame))
            _write_mask(out / frame.mask_path, labels[0], frame)
        entries.append(frame_entry(frame))
        splits[frame.split].append(frame.file_path)
        distorted |= frame.distortion is not None
    if not entries:
        raise ValueError("a dataset needs at least one frame")
    doc = {"camera_model": "OPENCV" if distorted else "PINHOLE"}
    if thermal_scale_k is not None:
        doc["thermal_scale_k"] = float(thermal_scale_k)
        doc["thermal_range_k"] = [float(v) for v in thermal_range_k]
    if points_xyz is not None:
        write_points_ply(out / POINTS_FILE, points_xyz, points_rgb)
        doc["ply_file_path"] = POINTS_FILE
    if mask_labels:
        doc["mask_labels"] = {str(k): v for k, v in sorted(mask_labels.items())}
    if explicit_splits:
        doc["train_filenames"], doc["test_filenames"] = splits["train"], splits["test"]
    doc["frames"] = entries
    for name, content in (sidecars or {}).items():
        (out / name).write_text(json.dumps(content, indent=1) + "\n")
    target = out / "transforms.json"
    tmp = target.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, target)
    return target
