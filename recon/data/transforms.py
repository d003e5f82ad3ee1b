"""Parse and validate `transforms.json` of a prepared dataset (no image is read here).

Rules beyond shared/FORMATS.md, all documented in docs/data.md:
- intrinsics (`fl_x fl_y cx cy w h`) and distortion (`k1 k2 p1 p2`) may sit at the top level
  as nerfstudio allows; a frame's own keys win;
- `thermal_scale_k` and `thermal_range_k` are required as soon as there is a thermal frame
  (a guessed scale would silently give wrong temperatures);
- splits: `test_filenames` alone -> every other frame is train; `train_filenames` alone ->
  every other frame is test; neither -> frames of camera `cam1` are test;
- a pose must be finite, have last row (0, 0, 0, 1) and a rotation with |R^T R - I| <= 1e-3
  and det(R) > 0 (scaled or mirrored poses are rejected);
- optional (an extension of FORMATS.md, no existing meaning changed): a frame's `mask_path`, an
  8-bit single-channel PNG of object labels the frame's size (0 = no object), and top-level
  `mask_labels` {"<label>": {"name": ..., "moving": true|false}} (without it every nonzero
  label counts as moving). Evaluation grades moving / hot / static regions with them.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from recon.data.errors import DatasetError
from recon.data.frame import MODALITIES, Distortion, Frame

CAMERA_MODELS = ("PINHOLE", "OPENCV")
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
DISTORTION_KEYS = ("k1", "k2", "p1", "p2")
RIGID_TOLERANCE = 1e-3
TEST_CAMERA = "cam1"


@dataclass
class Manifest:
    """What transforms.json says; frame intrinsics are as stored (before any undistortion)."""

    path: Path
    camera_model: str
    thermal_scale_k: float | None
    thermal_range_k: tuple[float, float] | None
    ply_file_path: str | None
    frames: list[Frame]
    mask_labels: dict[int, dict]   # {label: {"name", "moving"}}; empty when not given


def _number(value, where: str, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DatasetError(f"{where}: {what} must be a finite number, got {value!r}")
    return float(value)


def _pose(value, where: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: transform_matrix must be a 4x4 list of numbers") from None
    if m.shape != (4, 4):
        raise DatasetError(f"{where}: transform_matrix must be 4x4, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise DatasetError(f"{where}: transform_matrix has non-finite entries")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise DatasetError(f"{where}: transform_matrix last row must be 0 0 0 1, got {m[3].tolist()}")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > RIGID_TOLERANCE or np.linalg.det(r) <= 0:
        raise DatasetError(f"{where}: transform_matrix is not rigid (max |R^T R - I| = {err:.3g}, "
                           f"det R = {np.linalg.det(r):.4g}); scaled or mirrored poses are not allowed")
    return m


def _frame(raw, index: int, top: dict, camera_model: str, where_file: str) -> Frame:
    where = f"{where_file}: frames[{index}]"
    if not isinstance(raw, dict):
        raise DatasetError(f"{where}: must be an object")
    file_path = raw.get("file_path")
    if not isinstance(file_path, str) or not file_path:
        raise DatasetError(f"{where}: file_path missing or not a string")
    where = f"{where} ({file_path})"
    modality = raw.get("modality")
    if modality not in MODALITIES:
        raise DatasetError(f"{where}: unknown modality {modality!r}; expected 'rgb' or 'thermal'")
    camera = raw.get("camera")
    if not isinstance(camera, str) or not camera:
        raise DatasetError(f"{where}: camera missing or not a string (e.g. 'cam0')")
    if "time" not in raw:
        raise DatasetError(f"{where}: time missing")
    time = _number(raw["time"], where, "time")
    if not 0.0 <= time <= 1.0:
        raise DatasetError(f"{where}: time {time} is outside [0, 1]")
    timestamp = raw.get("timestamp_s")
    if timestamp is not None:
        timestamp = _number(timestamp, where, "timestamp_s")
    if "transform_matrix" not in raw:
        raise DatasetError(f"{where}: transform_matrix missing")
    c2w = _pose(raw["transform_matrix"], where)
    values = {}
    for key in INTRINSIC_KEYS + (DISTORTION_KEYS if camera_model == "OPENCV" else ()):
        value = raw.get(key, top.get(key))
        if value is None and key in DISTORTION_KEYS:
            value = 0.0
        if value is None:
            raise DatasetError(f"{where}: {key} missing (neither in the frame nor at the top level)")
        values[key] = _number(value, where, key)
    w, h = values["w"], values["h"]
    if w != int(w) or h != int(h) or w < 1 or h < 1:
        raise DatasetError(f"{where}: w and h must be positive integers, got {w} x {h}")
    if values["fl_x"] <= 0 or values["fl_y"] <= 0:
        raise DatasetError(f"{where}: focal lengths must be positive")
    distortion = None
    if camera_model == "OPENCV" and any(values[k] != 0 for k in DISTORTION_KEYS):
        distortion = Distortion(values["fl_x"], values["fl_y"], values["cx"], values["cy"],
                                *(values[k] for k in DISTORTION_KEYS))
    mask_path = raw.get("mask_path")
    if mask_path is not None and (not isinstance(mask_path, str) or not mask_path):
        raise DatasetError(f"{where}: mask_path must be a relative file path")
    return Frame(file_path, modality, camera, time, timestamp, c2w, values["fl_x"], values["fl_y"],
                 values["cx"], values["cy"], int(w), int(h), distortion=distortion, mask_path=mask_path)


def _mask_labels(value, where: str) -> dict[int, dict]:
    """{"3": {"name": "ball", "moving": true}, ...} -> {3: {...}}; labels 1..255."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise DatasetError(f"{where}: mask_labels must be an object mapping label ids to "
                           f'{{"name": ..., "moving": true|false}}')
    out = {}
    for key, info in value.items():
        if not str(key).isdigit() or not 1 <= int(key) <= 255:
            raise DatasetError(f"{where}: mask_labels key {key!r} must be a label id 1..255")
        if not isinstance(info, dict) or not isinstance(info.get("moving"), bool):
            raise DatasetError(f"{where}: mask_labels[{key}] needs a boolean 'moving'")
        out[int(key)] = {"name": str(info.get("name", f"object {key}")), "moving": info["moving"]}
    return out


def _assign_splits(frames: list[Frame], top: dict, where: str) -> list[Frame]:
    names = {f.file_path for f in frames}
    lists = {}
    for key in ("train_filenames", "test_filenames"):
        if key in top:
            value = top[key]
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise DatasetError(f"{where}: {key} must be a list of file paths")
            unknown = sorted(set(value) - names)
            if unknown:
                raise DatasetError(f"{where}: {key} lists files that are not frames: {unknown[:5]}")
            lists[key] = set(value)
    train, test = lists.get("train_filenames"), lists.get("test_filenames")
    if train is not None and test is not None and train & test:
        raise DatasetError(f"{where}: files in both train and test lists: {sorted(train & test)[:5]}")

    def split(frame: Frame) -> str:
        if test is not None:
            return "test" if frame.file_path in test else "train"
        if train is not None:
            return "train" if frame.file_path in train else "test"
        return "test" if frame.camera == TEST_CAMERA else "train"

    return [replace(f, split=split(f)) for f in frames]


def parse_transforms(path: Path) -> Manifest:
    """Read and validate a transforms.json; raises DatasetError naming the file and problem."""
    where = str(path)
    if not path.is_file():
        raise DatasetError(f"{where}: not found (a prepared dataset needs transforms.json)")
    try:
        top = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DatasetError(f"{where}: bad JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except UnicodeDecodeError as e:
        raise DatasetError(f"{where}: not UTF-8 text ({e.reason})") from None
    if not isinstance(top, dict):
        raise DatasetError(f"{where}: top level must be a JSON object")
    camera_model = top.get("camera_model", "PINHOLE")
    if camera_model not in CAMERA_MODELS:
        raise DatasetError(f"{where}: camera_model {camera_model!r} not supported; use "
                           f"{' or '.join(CAMERA_MODELS)}")
    raw_frames = top.get("frames")
    if not isinstance(raw_frames, list) or not raw_frames:
        raise DatasetError(f"{where}: 'frames' must be a non-empty list")
    frames = [_frame(raw, i, top, camera_model, where) for i, raw in enumerate(raw_frames)]
    seen = set()
    for f in frames:
        if f.file_path in seen:
            raise DatasetError(f"{where}: file_path {f.file_path} appears in more than one frame")
        seen.add(f.file_path)
    scale, span = top.get("thermal_scale_k"), top.get("thermal_range_k")
    if any(f.modality == "thermal" for f in frames) or scale is not None or span is not None:
        if scale is None or span is None:
            raise DatasetError(f"{where}: thermal frames need thermal_scale_k and thermal_range_k")
        scale = _number(scale, where, "thermal_scale_k")
        if scale <= 0:
            raise DatasetError(f"{where}: thermal_scale_k must be positive, got {scale}")
        if not isinstance(span, list) or len(span) != 2:
            raise DatasetError(f"{where}: thermal_range_k must be [min, max] kelvin")
        span = (_number(span[0], where, "thermal_range_k[0]"), _number(span[1], where, "thermal_range_k[1]"))
        if not 0 <= span[0] < span[1]:
            raise DatasetError(f"{where}: thermal_range_k must satisfy 0 <= min < max, got {list(span)}")
    ply = top.get("ply_file_path")
    if ply is not None and not isinstance(ply, str):
        raise DatasetError(f"{where}: ply_file_path must be a string")
    return Manifest(path, camera_model, scale, span, ply, _assign_splits(frames, top, where),
                    _mask_labels(top.get("mask_labels"), where))
