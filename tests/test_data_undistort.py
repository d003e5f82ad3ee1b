"""OPENCV lens model: distorted frames load as the pinhole frames the world renders."""
import cv2
import numpy as np
import pytest

from recon.data import Distortion, Frame, c2w_opencv_to_opengl, load_dataset, write_dataset
from rig.sim import make_world

W, H, T = 160, 120, 5.0
COEFFS = (-0.25, 0.08, 0.001, -0.0005)  # barrel: ~5 px at the corners of a 42 degree view


@pytest.fixture(scope="module")
def world():
    return make_world("default", 0)


def _render(world, modality, c2w, fx, fy, cx, cy, width, height):
    if modality == "rgb":
        return world.render_rgb(c2w, fx, fy, cx, cy, width, height, T).astype(np.float32) / 255
    return world.render_temperature(c2w, fx, fy, cx, cy, width, height, T).astype(np.float32)


def _distorted(world, modality, c2w, k):
    """What a camera with pinhole part k and COEFFS sees, resampled from a wide 2x render."""
    ref = dict(fx=k.fx * 1.2, fy=k.fy * 1.2, cx=W, cy=H, width=2 * W, height=2 * H)
    wide = _render(world, modality, c2w, **ref)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))  # OpenCV centres
    k_cv = np.array([[k.fx, 0, k.cx - 0.5], [0, k.fy, k.cy - 0.5], [0, 0, 1]])
    norm = cv2.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2), k_cv,
                               np.array(COEFFS)).reshape(H, W, 2)
    map_x = (ref["fx"] * norm[..., 0] + ref["cx"] - 0.5).astype(np.float32)
    map_y = (ref["fy"] * norm[..., 1] + ref["cy"] - 0.5).astype(np.float32)
    return cv2.remap(wide, map_x, map_y, cv2.INTER_LINEAR)


def _load_distorted(tmp_path, world, modality):
    c2w = world.rig_pose(0, T)[0]
    k = world.rig_config.rgb.scaled(W, H)  # the wider lens, where distortion shows
    image = _distorted(world, modality, c2w, k)
    pixels = (np.round(image * 255).astype(np.uint8) if modality == "rgb"
              else world.thermal_counts(image, None))
    d = Distortion(k.fx, k.fy, k.cx, k.cy, *COEFFS)
    frame = Frame(f"{modality}/0.png", modality, "cam0", 0.5, None, c2w_opencv_to_opengl(c2w),
                  k.fx, k.fy, k.cx, k.cy, W, H, distortion=d)
    write_dataset(tmp_path, [(frame, pixels)], 0.01, (270.0, 400.0))
    ds = load_dataset(tmp_path)
    return ds, ds.frames[0], image, c2w, k


def test_rgb_undistorts_to_the_reported_pinhole(tmp_path, world):
    ds, frame, distorted, c2w, k = _load_distorted(tmp_path, world, "rgb")
    assert '"camera_model": "OPENCV"' in (tmp_path / "transforms.json").read_text()
    assert frame.distortion.k1 == COEFFS[0] and frame.fx != k.fx  # pinhole intrinsics now
    loaded = ds.image(frame)
    pinhole = (frame.fx, frame.fy, frame.cx, frame.cy, W, H)
    err = np.abs(loaded - _render(world, "rgb", c2w, *pinhole)).mean()
    assert err < 0.02
    # both a lens model ignored and a half-pixel convention slip are clearly worse
    ignored = np.abs(distorted - _render(world, "rgb", c2w, k.fx, k.fy, k.cx, k.cy, W, H)).mean()
    shifted = np.abs(loaded - _render(world, "rgb", c2w, frame.fx, frame.fy, frame.cx + 0.5,
                                      frame.cy + 0.5, W, H)).mean()
    assert ignored > 1.8 * err and shifted > 1.6 * err, (err, ignored, shifted)


def test_thermal_undistorts_and_keeps_kelvin(tmp_path, world):
    ds, frame, _, c2w, _ = _load_distorted(tmp_path, world, "thermal")
    kelvin = ds.image(frame)
    truth = _render(world, "thermal", c2w, frame.fx, frame.fy, frame.cx, frame.cy, W, H)
    valid = np.isfinite(kelvin)
    assert valid.mean() > 0.99  # alpha = 0: every output pixel sees the input image
    err = np.abs(kelvin[valid] - truth[valid])
    assert np.median(err) < 0.02 and err.mean() < 0.3
