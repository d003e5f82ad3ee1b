"""The heated checkerboard: OpenCV finds it in both modalities where the ground truth says."""
import cv2
import numpy as np
import pytest

from rig.sim.calibration import make_calibration_world

SIZE = (320, 240)


@pytest.fixture(scope="module")
def world():
    return make_calibration_world(seed=0)


def _detect(gray, pattern):
    found, corners = cv2.findChessboardCorners(gray, pattern)
    assert found
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (5, 5), (-1, -1), criteria)
    return refined.reshape(-1, 2) + 0.5  # OpenCV pixel centres are integers, ours at +0.5


def _project(points, c2w, k):
    cam = (np.linalg.inv(c2w) @ np.c_[points, np.ones(len(points))].T)[:3].T
    return np.stack([k.fx * cam[:, 0] / cam[:, 2] + k.cx, k.fy * cam[:, 1] / cam[:, 2] + k.cy], 1)


@pytest.mark.parametrize("rig, t", [(0, 2.0), (1, 4.0)])
def test_detected_corners_match_projected_ground_truth(world, rig, t):
    target = world.scene.target
    truth = world.scene.inner_corners_world()
    c2w_rgb, c2w_th = world.rig_pose(rig, t)
    ki, kt = world.rig_config.rgb.scaled(*SIZE), world.rig_config.thermal.scaled(*SIZE)
    rgb = world.render_rgb(c2w_rgb, ki.fx, ki.fy, ki.cx, ki.cy, *SIZE, t)
    kelvin = world.render_temperature(c2w_th, kt.fx, kt.fy, kt.cx, kt.cy, *SIZE, t)
    thermal8 = np.clip((kelvin - 290) / 40 * 255, 0, 255).astype(np.uint8)
    for gray, c2w, k, tol in ((cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), c2w_rgb, ki, 0.3),
                              (thermal8, c2w_th, kt, 0.1)):
        found = _detect(gray, target.pattern_size)
        err = np.linalg.norm(found[:, None] - _project(truth, c2w, k)[None], axis=2).min(axis=1)
        assert len(found) == 48 and err.max() < tol, err.max()


def test_black_squares_are_the_warm_ones(world):
    albedo, kelvin = world.scene.target.face_textures()
    dark = albedo.image[..., 0] < 0.5
    assert kelvin.image[dark, 0].mean() > kelvin.image[~dark, 0].mean() + 10
