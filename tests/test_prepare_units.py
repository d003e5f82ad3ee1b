"""Pieces of `recon prepare` against known values: pose interpolation and alignment, path
jitter, metric scale from a triangulated checkerboard, thermal downscaling, pair lists."""
import cv2
import numpy as np
import pytest

from recon.prepare.recover import spans
from recon.prepare.writing import dataset_intrinsics, downscale_counts, max_distortion_px
from recon.prepare.poses import (apply_similarity, interpolate_pose, matrix_from_quat, path_jitter_deg,
                                 pose_errors, quat_from_matrix, umeyama)
from recon.prepare.scale import scale_from_target
from recon.sfm import sequential_pairs
from rig.calibrate import Lens, Target
from rig.sim.camera import look_at, rotation


def _random_rotation(rng):
    q = rng.normal(size=4)
    return matrix_from_quat(q / np.linalg.norm(q))


def test_quaternion_round_trip_and_slerp_midpoint():
    rng = np.random.default_rng(0)
    for _ in range(20):
        r = _random_rotation(rng)
        np.testing.assert_allclose(matrix_from_quat(quat_from_matrix(r)), r, atol=1e-12)
    a, b = np.eye(4), np.eye(4)
    b[:3, :3], b[:3, 3] = rotation("z", np.radians(40)), [2.0, 0, 0]
    mid = interpolate_pose(np.array([0.0, 1.0]), np.stack([a, b]), 0.25)
    np.testing.assert_allclose(mid[:3, :3], rotation("z", np.radians(10)), atol=1e-12)
    np.testing.assert_allclose(mid[:3, 3], [0.5, 0, 0])
    np.testing.assert_allclose(interpolate_pose(np.array([0.0, 1.0]), np.stack([a, b]), 3.0), b)


def test_umeyama_recovers_a_similarity_and_pose_errors_vanish():
    rng = np.random.default_rng(1)
    truth = np.stack([look_at(rng.normal(size=3) * 2, np.zeros(3)) for _ in range(10)])
    s, r = 0.37, _random_rotation(rng)
    t = rng.normal(size=3)
    moved = np.stack([apply_similarity(s, r, t, c) for c in truth])
    s2, r2, t2 = umeyama(moved[:, :3, 3], truth[:, :3, 3])
    assert s2 == pytest.approx(1 / s)
    e = pose_errors(moved, truth)
    assert e["rotation_deg"].max() < 1e-5 and e["position"].max() < 1e-9


def test_path_jitter_is_zero_on_a_smooth_path_and_sees_a_kink():
    times = np.linspace(0, 1, 9)
    path = np.stack([look_at(np.array([np.cos(a), np.sin(a), 0.5]), np.zeros(3)) for a in times * 0.5])
    assert path_jitter_deg(times, path).max() < 0.05
    path[4, :3, :3] = path[4, :3, :3] @ rotation("x", np.radians(2.0))
    j = path_jitter_deg(times, path)
    assert j[3] == pytest.approx(2.0, abs=0.1) and np.delete(j, [2, 3, 4]).max() < 0.05


def test_scale_from_a_triangulated_checkerboard():
    """Board corners projected into three views of a scene in 'SfM units' (metres / 0.25)."""
    target = Target((8, 6), 0.016)
    units = 0.25                                    # metres per unit
    board = (target.object_points() - [0.056, 0.04, 0]) / units
    k = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
    corners, c2ws, ks, dists = {}, {}, {}, {}
    for i, eye in enumerate([[0.0, -0.5, -2.4], [0.6, -0.3, -2.2], [-0.5, 0.2, -2.3]]):
        c2w = look_at(np.array(eye), np.zeros(3), up=np.array([0, -1.0, 0]))
        w2c = np.linalg.inv(c2w)
        uv, _ = cv2.projectPoints(board @ w2c[:3, :3].T + w2c[:3, 3], np.zeros(3), np.zeros(3), k, None)
        corners[f"{i}"], c2ws[f"{i}"], ks[f"{i}"], dists[f"{i}"] = uv[:, 0], c2w, k, np.zeros(4)
    est = scale_from_target(corners, c2ws, ks, dists, target.pattern, target.square_m)
    assert est.method == "target" and est.metres_per_unit == pytest.approx(units, rel=1e-6)
    assert scale_from_target(dict(list(corners.items())[:2]), c2ws, ks, dists, target.pattern, 0.016) is None
    corners["2"] = corners["2"][::-1]               # inconsistent corner order in one view
    assert scale_from_target(corners, c2ws, ks, dists, target.pattern, 0.016).metres_per_unit is None


def test_downscaled_thermal_counts_average_and_keep_holes():
    counts = np.arange(1, 65, dtype=np.uint16).reshape(8, 8) * 100
    counts[0, 0] = 0
    out = downscale_counts(counts, 2)
    assert out.shape == (4, 4) and out[0, 0] == 0
    assert out[1, 1] == np.round(counts[2:4, 2:4].astype(float).mean())


def test_negligible_lens_distortion_is_written_as_pinhole():
    assert max_distortion_px(800, 800, 320, 240, 640, 480, np.array([1e-4, 0, 0, 0])) < 0.1
    k, d = dataset_intrinsics(Lens(640, 480, 800, 800, 320, 240, 1e-4), 2)
    assert d is None and k == (400, 400, 160, 120)
    k, d = dataset_intrinsics(Lens(640, 480, 800, 800, 320, 240, -0.1, 0.01), 1)
    assert d is not None and d.k1 == -0.1 and d.fx == 800


def test_sequential_pairs_have_neighbours_jumps_and_loop_keyframes():
    pairs = set(sequential_pairs(30, 3, 10))
    assert {(0, 1), (0, 3), (5, 8), (0, 4), (0, 16)} <= pairs        # overlap, 2^k jumps
    assert (10, 20) in pairs and (0, 20) in pairs                       # keyframes 0, 10, 20
    assert (5, 10) not in pairs and all(i < j for i, j in pairs)


def test_time_spans_summary():
    assert spans([1.0, 1.2, 1.4, 5.0]) == "1.0-1.4, 5.0"
    assert spans([]) == "-"
