"""Image files of a prepared dataset: header checks, decoding, undistortion.

RGB: 8-bit PNG or JPEG, 3 channels (an alpha channel is dropped) -> float32 (H, W, 3) in [0, 1].
Thermal: 16-bit single-channel PNG of counts -> float32 (H, W) kelvin = count * scale, NaN where
the count is 0 ("no measurement").

OPENCV lens model: images are undistorted to a pinhole camera when loaded. The new camera
matrix is OpenCV's optimal one with alpha = 0 (every output pixel sees the input image), so
the frame's fx, fy, cx, cy change and are reported by the loaded `Frame`. OpenCV's pixel
centres are integers while the dataset's are at +0.5, so principal points are shifted by
0.5 px on the way in and out. Thermal kelvin are interpolated bilinearly and a pixel stays
valid only if all its source pixels were valid.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from recon.data.errors import DatasetError
from recon.data.frame import Distortion

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # colour type -> channels after decoding


@dataclass(frozen=True)
class ImageHeader:
    width: int
    height: int
    channels: int
    bits: int


def read_header(path: Path) -> ImageHeader:
    """Size, channels and bit depth from the file header, without decoding pixels."""
    with open(path, "rb") as f:
        head = f.read(33)
    if head[:8] == PNG_SIGNATURE and head[12:16] == b"IHDR":
        width, height, bits, color_type = struct.unpack(">IIBB", head[16:26])
        if color_type not in PNG_CHANNELS:
            raise DatasetError(f"{path}: PNG colour type {color_type} is not valid")
        return ImageHeader(width, height, PNG_CHANNELS[color_type], 8 if color_type == 3 else bits)
    try:
        with Image.open(path) as im:
            return ImageHeader(im.width, im.height, len(im.getbands()), 8)
    except (UnidentifiedImageError, OSError) as e:
        raise DatasetError(f"{path}: not a readable image ({e})") from None


def check_header(path: Path, modality: str, width: int, height: int) -> None:
    """Raise DatasetError unless the file matches the frame's modality and w x h."""
    if not path.is_file():
        raise DatasetError(f"{path}: image missing")
    header = read_header(path)
    if (header.width, header.height) != (width, height):
        raise DatasetError(f"{path}: image is {header.width}x{header.height} but the frame says "
                           f"w x h = {width}x{height}")
    if modality == "thermal" and (header.channels, header.bits) != (1, 16):
        raise DatasetError(f"{path}: thermal images must be 16-bit single-channel PNG, got "
                           f"{header.channels} channel(s) of {header.bits} bit")
    if modality == "rgb" and (header.bits != 8 or header.channels not in (3, 4)):
        raise DatasetError(f"{path}: RGB images must be 8-bit RGB(A), got {header.channels} "
                           f"channel(s) of {header.bits} bit")


def read_raw(path: Path) -> np.ndarray:
    """Stored pixels: uint8 (H, W, 3) RGB (alpha dropped) or uint16 (H, W) thermal counts."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: could not decode image")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


def read_mask(path: Path, width: int, height: int) -> np.ndarray:
    """An object-label image: uint8 (H, W), checked to be single-channel 8-bit and w x h."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: could not decode the mask image")
    if img.ndim != 2 or img.dtype != np.uint8:
        raise DatasetError(f"{path}: masks must be 8-bit single-channel PNG, got {img.dtype} "
                           f"with shape {img.shape}")
    if img.shape != (height, width):
        raise DatasetError(f"{path}: mask is {img.shape[1]}x{img.shape[0]} but its frame is {width}x{height}")
    return img


def decode_rgb(raw: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) -> float32 (H, W, 3) in [0, 1]."""
    return raw.astype(np.float32) / np.float32(255)


def decode_thermal(counts: np.ndarray, scale_k: float) -> np.ndarray:
    """uint16 (H, W) counts -> float32 (H, W) kelvin, NaN where the count is 0."""
    kelvin = counts.astype(np.float32) * np.float32(scale_k)
    kelvin[counts == 0] = np.nan
    return kelvin


def _opencv_k(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """K (3, 3) in OpenCV's pixel convention from dataset intrinsics (centres at +0.5)."""
    return np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]])


def undistorted_intrinsics(d: Distortion, width: int, height: int) -> tuple[float, float, float, float]:
    """Pinhole (fx, fy, cx, cy) of the undistorted image (dataset pixel convention)."""
    new_k, _ = cv2.getOptimalNewCameraMatrix(_opencv_k(d.fx, d.fy, d.cx, d.cy), d.coefficients(),
                                             (width, height), 0.0)
    return float(new_k[0, 0]), float(new_k[1, 1]), float(new_k[0, 2]) + 0.5, float(new_k[1, 2]) + 0.5


@lru_cache(maxsize=16)
def _undistort_maps(d: Distortion, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    new_k = _opencv_k(*undistorted_intrinsics(d, width, height))
    return cv2.initUndistortRectifyMap(_opencv_k(d.fx, d.fy, d.cx, d.cy), d.coefficients(), None,
                                       new_k, (width, height), cv2.CV_32FC1)


def undistort(image: np.ndarray, d: Distortion) -> np.ndarray:
    """Undistort a decoded float32 image (RGB or NaN-masked kelvin) to the pinhole camera."""
    h, w = image.shape[:2]
    map_x, map_y = _undistort_maps(d, w, h)
    if image.ndim == 3:
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    valid = np.isfinite(image)
    filled = np.where(valid, image, 0).astype(np.float32)
    out = cv2.remap(filled, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    coverage = cv2.remap(valid.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out[coverage < 1 - 1e-4] = np.nan
    return out
