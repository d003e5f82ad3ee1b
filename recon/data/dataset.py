"""A loaded prepared dataset: validated frames, lazily decoded images, initial points."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from recon.data import images
from recon.data.cache import ByteLRU
from recon.data.errors import DatasetError
from recon.data.frame import MODALITIES, SPLITS, Frame
from recon.data.ply import read_points_ply
from recon.data.transforms import parse_transforms

DEFAULT_CACHE_BYTES = 1 << 30  # 1 GiB of decoded images: ~270 RGB or ~870 thermal 640x480 frames


class Dataset:
    """Frames and metadata of a prepared dataset (shared/FORMATS.md); images decode on demand.

    `image(frame)` returns float32 RGB (H, W, 3) in [0, 1] or float32 thermal (H, W) kelvin with
    NaN where nothing was measured (count 0); use np.isfinite(...) as the valid mask. Decoded
    images are kept in a least-recently-used cache of at most `cache_bytes`.
    """

    def __init__(self, root: Path, frames: list[Frame], camera_model: str,
                 thermal_scale_k: float | None, thermal_range_k: tuple[float, float] | None,
                 points_xyz: np.ndarray | None, points_rgb: np.ndarray | None,
                 cache_bytes: int = DEFAULT_CACHE_BYTES, mask_labels: dict[int, dict] | None = None):
        self.root = root
        self.frames = frames
        self.camera_model = camera_model
        self.thermal_scale_k = thermal_scale_k
        self.thermal_range_k = thermal_range_k
        self.points_xyz = points_xyz
        self.points_rgb = points_rgb
        self.mask_labels = mask_labels or {}
        self._cache = ByteLRU(cache_bytes)

    def __len__(self) -> int:
        return len(self.frames)

    def path(self, frame: Frame) -> Path:
        return self.root / frame.file_path

    def read_raw(self, frame: Frame) -> np.ndarray:
        """The stored pixels, undecoded and not cached: uint8 (H, W, 3) or uint16 counts (H, W)."""
        return images.read_raw(self.path(frame))

    def image(self, frame: Frame) -> np.ndarray:
        """Decoded (and undistorted) image, read-only and cached; see the class docstring."""
        return self._cache.get(frame.file_path, lambda: self._decode(frame))

    def _decode(self, frame: Frame) -> np.ndarray:
        raw = self.read_raw(frame)
        if frame.modality == "rgb":
            img = images.decode_rgb(raw)
        else:
            img = images.decode_thermal(raw, self.thermal_scale_k)
        return images.undistort(img, frame.distortion) if frame.distortion else img

    def mask(self, frame: Frame) -> np.ndarray | None:
        """The frame's object labels, uint8 (H, W), read-only and cached; None without a mask."""
        if frame.mask_path is None:
            return None
        return self._cache.get("mask:" + frame.mask_path, lambda: self._read_mask(frame))

    def _read_mask(self, frame: Frame) -> np.ndarray:
        path = self.root / frame.mask_path
        labels = images.read_mask(path, frame.width, frame.height)
        unknown = sorted(set(np.unique(labels).tolist()) - {0} - set(self.mask_labels)) if self.mask_labels else []
        if unknown:
            raise DatasetError(f"{path}: labels {unknown[:5]} are not in transforms.json mask_labels")
        labels.flags.writeable = False
        return labels

    def split(self, modality: str, split: str) -> list[Frame]:
        """Frames of one modality ('rgb' | 'thermal') and split ('train' | 'test'), file order."""
        if modality not in MODALITIES or split not in SPLITS:
            raise ValueError(f"modality must be one of {MODALITIES} and split one of {SPLITS}")
        return [f for f in self.frames if f.modality == modality and f.split == split]

    def times(self) -> np.ndarray:
        """Sorted unique normalised times (K,) float64."""
        return np.unique([f.time for f in self.frames])

    def cameras(self) -> list[str]:
        return sorted({f.camera for f in self.frames})

    @property
    def cache_bytes_used(self) -> int:
        return self._cache.nbytes


def load_dataset(path: str | Path, cache_bytes: int = DEFAULT_CACHE_BYTES) -> Dataset:
    """Load and validate a prepared dataset folder (or its transforms.json).

    Checks every frame's metadata, that each image exists with the frame's w x h and the
    modality's encoding (headers only; pixels decode lazily), and the optional points PLY
    (`ply_file_path`, else `points3d.ply` if present). Raises DatasetError naming the file and
    the problem.
    """
    path = Path(path)
    transforms = path if path.suffix == ".json" else path / "transforms.json"
    root = transforms.parent
    manifest = parse_transforms(transforms)
    frames = []
    for frame in manifest.frames:
        images.check_header(root / frame.file_path, frame.modality, frame.width, frame.height)
        if frame.mask_path is not None and not (root / frame.mask_path).is_file():
            raise DatasetError(f"{root / frame.mask_path}: mask of {frame.file_path} missing")
        if frame.distortion is not None:
            fx, fy, cx, cy = images.undistorted_intrinsics(frame.distortion, frame.width, frame.height)
            frame = replace(frame, fx=fx, fy=fy, cx=cx, cy=cy)
        frames.append(frame)
    ply = root / (manifest.ply_file_path or "points3d.ply")
    if manifest.ply_file_path and not ply.is_file():
        raise DatasetError(f"{transforms}: ply_file_path {manifest.ply_file_path} does not exist")
    xyz, rgb = read_points_ply(ply) if ply.is_file() else (None, None)
    return Dataset(root, frames, manifest.camera_model, manifest.thermal_scale_k,
                   manifest.thermal_range_k, xyz, rgb, cache_bytes, manifest.mask_labels)
