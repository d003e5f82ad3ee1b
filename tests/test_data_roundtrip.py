"""simulate -> write -> load gives back exactly what the world rendered."""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from recon.cli import main as recon_main
from recon.data import Frame, load_dataset, write_dataset
from recon.data.simulate import SimulateConfig, render_step, simulate_dataset
from rig.sim import make_world

CFG = SimulateConfig(frames=3, width=32, height=24, seed=11, points=300)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    simulate_dataset(out, CFG)
    return out


def test_loaded_pixels_poses_and_intrinsics_equal_what_was_rendered(simulated):
    ds = load_dataset(simulated)
    assert len(ds) == CFG.frames * 2 * 2
    world = make_world(CFG.variant, CFG.seed)
    by_path = {f.file_path: f for f in ds.frames}
    for step in range(CFG.frames):
        for frame, pixels, labels in render_step(CFG, step):
            loaded = by_path[frame.file_path]
            np.testing.assert_array_equal(ds.read_raw(loaded), pixels)
            np.testing.assert_array_equal(ds.mask(loaded), labels)
            np.testing.assert_array_equal(loaded.c2w, frame.c2w)
            assert (loaded.fx, loaded.fy, loaded.cx, loaded.cy) == (frame.fx, frame.fy, frame.cx, frame.cy)
            assert loaded.time == frame.time and loaded.timestamp_s == frame.timestamp_s
            if frame.modality == "rgb":
                np.testing.assert_array_equal(ds.image(loaded), pixels.astype(np.float32) / 255)
            else:
                kelvin = ds.image(loaded)
                np.testing.assert_allclose(kelvin, pixels * 0.01, rtol=1e-6)
    # the stored pose is the world's camera, converted to OpenGL axes and back
    thermal0 = by_path["thermal/000001_cam0.png"]
    np.testing.assert_allclose(thermal0.c2w_opencv(), world.rig_pose(0, thermal0.timestamp_s)[1],
                               atol=1e-12)


def test_viewmat_projects_like_the_simulator_camera(simulated):
    ds = load_dataset(simulated)
    frame = ds.split("thermal", "test")[1]
    world = make_world(CFG.variant, CFG.seed)
    _, c2w = world.rig_pose(1, frame.timestamp_s)
    point = np.array([0.05, -0.02, 0.01, 1.0])
    cam_sim = np.linalg.inv(c2w) @ point
    cam_ds = frame.viewmat().astype(np.float64) @ point
    np.testing.assert_allclose(cam_ds, cam_sim, atol=1e-6)
    assert frame.viewmat().dtype == np.float32


def test_splits_times_points_and_metadata(simulated):
    ds = load_dataset(simulated)
    assert {f.camera for f in ds.split("rgb", "test")} == {"cam1"}
    assert {f.camera for f in ds.split("thermal", "train")} == {"cam0"}
    np.testing.assert_allclose(ds.times(), [0.0, 0.5, 1.0])
    assert ds.thermal_scale_k == 0.01
    lo, hi = ds.thermal_range_k
    assert lo < np.nanmin(ds.image(ds.frames[1])) and np.nanmax(ds.image(ds.frames[1])) < hi
    assert ds.points_xyz.shape == (300, 3) and ds.points_rgb.dtype == np.uint8
    assert np.abs(ds.points_xyz).max() < 3.0  # inside the room
    assert (simulated / "sim_meta.json").is_file()


def test_same_seed_same_bytes_in_any_number_of_processes(simulated, tmp_path):
    simulate_dataset(tmp_path / "again", replace(CFG, jobs=2))
    assert _files(tmp_path / "again") == _files(simulated)
    simulate_dataset(tmp_path / "other", replace(CFG, seed=12))
    other = _files(tmp_path / "other")
    assert other["rgb/000000_cam0.png"] != _files(simulated)["rgb/000000_cam0.png"]


def test_writer_round_trips_explicit_splits_jpeg_and_thermal_zeros(tmp_path):
    rng = np.random.default_rng(0)
    c2w = np.eye(4)
    c2w[:3, 3] = [0.1, 0.2, 0.3]
    counts = rng.integers(20000, 40000, size=(6, 8), dtype=np.uint16)
    counts[0, :3] = 0
    rgb = rng.integers(0, 256, size=(6, 8, 3), dtype=np.uint8)
    flat = np.full((6, 8, 3), (200, 120, 40), np.uint8)
    frames = [
        (Frame("t/a.png", "thermal", "camA", 0.0, None, c2w, 10, 11, 4, 3, 8, 6, "test"), counts),
        (Frame("c/a.png", "rgb", "camA", 1.0, 2.5, c2w, 10, 11, 4, 3, 8, 6, "train"), rgb),
        (Frame("c/b.jpg", "rgb", "camB", 0.5, None, c2w, 10, 11, 4, 3, 8, 6, "train"), flat),
    ]
    write_dataset(tmp_path, iter(frames), 0.1, (250.0, 400.0), explicit_splits=True)
    ds = load_dataset(tmp_path / "transforms.json")
    assert [f.split for f in ds.frames] == ["test", "train", "train"]
    np.testing.assert_array_equal(ds.read_raw(ds.frames[0]), counts)
    kelvin = ds.image(ds.frames[0])
    assert np.isnan(kelvin[0, :3]).all() and np.isfinite(kelvin[1:]).all()
    np.testing.assert_allclose(kelvin[1:], counts[1:] * 0.1, rtol=1e-6)
    np.testing.assert_array_equal(ds.read_raw(ds.frames[1]), rgb)
    assert np.abs(ds.read_raw(ds.frames[2]).astype(int) - flat).max() <= 3  # JPEG: lossy
    assert ds.points_xyz is None and ds.frames[0].timestamp_s is None
    with pytest.raises(ValueError, match="read-only"):
        ds.image(ds.frames[0])[0, 0] = 1.0


def test_writer_rejects_pixels_that_do_not_match_the_frame(tmp_path):
    frame = Frame("t/a.png", "thermal", "cam0", 0.0, None, np.eye(4), 10, 10, 4, 3, 8, 6)
    with pytest.raises(ValueError, match="uint16"):
        write_dataset(tmp_path, [(frame, np.zeros((6, 8), np.uint8))], 0.01, (250.0, 400.0))


def test_cli_writes_a_dataset_and_refuses_a_full_folder(tmp_path, capsys):
    out = tmp_path / "cli"
    assert recon_main(["simulate", str(out), "--frames", "2", "--size", "16x12", "--rigs", "1",
                       "--points", "50", "--variant", "rapid"]) == 0
    ds = load_dataset(out)
    assert len(ds) == 4 and ds.cameras() == ["cam0"]
    assert recon_main(["simulate", str(out), "--frames", "2"]) == 2
    assert "not empty" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        recon_main(["simulate", str(tmp_path / "x"), "--size", "16by12"])
