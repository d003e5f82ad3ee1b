"""`recon run` / `recon render` end to end on a tiny simulated dataset; `recon run SESSION` when
`recon prepare` refuses the session."""
import json
import subprocess
import sys
from dataclasses import asdict

import numpy as np
import pytest
from PIL import Image

from recon.cli import main as recon_main
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.prepare import REPORT_FILE
from recon.splat.ply import read_gaussians_ply
from rig.calibrate import Lens, RigCalibration
from rig.capture.config import CaptureConfig
from rig.capture.session_capture import Capture
from rig.sim.rig_config import RigConfig


def recon(*args, check=True):
    return subprocess.run([sys.executable, "-m", "recon", *map(str, args)], capture_output=True, text=True,
                          check=check)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    data = root / "data"
    simulate_dataset(data, SimulateConfig(frames=4, width=40, height=30, seed=1, points=300))
    out = root / "run"
    recon("run", data, "--out", out, "--iterations", 20, "--threads", 1)
    return data, out


def test_run_writes_renders_metrics_exports(run):
    data, out = run
    ds = load_dataset(data)
    for f in ds.split("rgb", "test") + ds.split("thermal", "test"):
        img = np.asarray(Image.open(out / "renders" / f.file_path))
        assert img.shape[:2] == (f.height, f.width)
        assert img.dtype == (np.uint8 if f.modality == "rgb" else np.uint16)
    summary = json.loads((out / "metrics.json").read_text())
    assert summary["iterations"] == 20
    assert set(summary["metrics"]) == {"rgb", "thermal", "regions", "objects"}
    objects = summary["metrics"]["objects"]["thermal"]      # the simulator names its objects
    assert objects and all(m["pixels"] > 0 and m["mae_k"] >= 0 for m in objects.values())
    assert summary["metrics"]["thermal"]["mae_k"] > 0
    assert sum(summary["gaussians_per_role"].values()) == summary["gaussians"]
    assert (out / "eval" / "metrics.md").exists() and (out / "animation.gif").exists()
    assert any((out / "strips").glob("thermal_*.png"))
    ply = read_gaussians_ply(out / "export" / "model.ply")
    assert len(ply.means) == summary["gaussians"]
    assert {"thermal_dc", "opacity_thermal", "role"} <= set(ply.extra)


def test_resume_continues_to_a_larger_budget(run):
    data, out = run
    res = recon("run", data, "--out", out, "--resume", "--iterations", 30, "--threads", 1)
    assert "resumed" in res.stdout and "iteration 20" in res.stdout
    assert json.loads((out / "metrics.json").read_text())["iterations"] == 30


def test_render_any_time_and_pose(run, tmp_path):
    _, out = run
    facts = json.loads((out / "scene.json").read_text())
    pose = np.asarray(facts["camera"]["c2w"])
    pose[:3, 3] += 0.02
    (tmp_path / "pose.json").write_text(json.dumps(pose.tolist()))
    res = recon("render", out, "--time", 0.37, "--pose", tmp_path / "pose.json", "--out", tmp_path / "r")
    assert "temperature at t=0.37" in res.stdout
    thermal = np.asarray(Image.open(tmp_path / "r_thermal.png"))
    assert thermal.dtype == np.uint16 and thermal.min() >= 1
    assert np.asarray(Image.open(tmp_path / "r_rgb.png")).shape == (facts["camera"]["height"], facts["camera"]["width"], 3)


def test_clear_errors(tmp_path):
    res = recon("run", tmp_path, "--out", tmp_path / "o", check=False)
    assert res.returncode == 2 and "neither a prepared dataset (transforms.json), a rig session" in res.stderr
    assert "RGBT-Scenes folder" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = recon("render", tmp_path, check=False)
    assert res.returncode != 0 and "missing" in res.stderr


@pytest.fixture(scope="module")
def textureless_session(tmp_path_factory):
    """2 s of the simulated rig's `synthetic` scene: warm blobs on a smooth background, no SIFT
    features, and no calibration in the session."""
    path = tmp_path_factory.mktemp("session") / "s"
    Capture(CaptureConfig(duration_s=2.0, out=path, progress=False, sim_scene="synthetic")).run()
    return path


def _calibration_file(path):
    rc = RigConfig()
    return RigCalibration(Lens(**asdict(rc.rgb)), Lens(**asdict(rc.thermal)), rc.thermal_from_rgb).save(path)


def _refused(res, *phrases):
    """One clean paragraph on stderr (no traceback) with `phrases` and where the report is."""
    assert res.returncode == 2 and "Traceback" not in res.stderr
    msg = [line for line in res.stderr.splitlines() if line.startswith("recon run:")]
    assert len(msg) == 1 and "nothing trained" in msg[0] and REPORT_FILE in msg[0]
    assert all(p in msg[0] for p in phrases), msg[0]


def test_a_refused_session_is_a_message_not_a_traceback(textureless_session, tmp_path):
    res = recon("run", textureless_session, "--out", tmp_path / "a", check=False)
    _refused(res, "no rig calibration", "rig calibrate")
    assert json.loads((tmp_path / "a" / "data" / REPORT_FILE).read_text())["status"] == "failed"

    cal = _calibration_file(tmp_path / "rig.json")
    res = recon("run", textureless_session, "--out", tmp_path / "b", "--calibration", cal, "--frames", 6,
                "--scale", 0.1, "--downscale", 2, check=False)
    _refused(res, "too few matches", "Recapture")
    report = json.loads((tmp_path / "b" / "data" / REPORT_FILE).read_text())
    assert report["calibration"]["source"] == str(cal)                    # the options reached prepare
    assert {k: report["options"][k] for k in ("frames", "scale", "downscale")} == {"frames": 6, "scale": 0.1,
                                                                                  "downscale": 2}
    assert not (tmp_path / "b" / "metrics.json").exists()


def test_follow_on_a_session_that_never_prepares_is_a_message(textureless_session, tmp_path):
    res = recon("run", textureless_session, "--follow", "--out", tmp_path / "f", check=False)
    _refused(res, "capture ended before poses could be recovered", "no rig calibration")


def test_bad_prepare_options_are_usage_errors(textureless_session, tmp_path, capsys):
    assert recon_main(["run", str(textureless_session), "--out", str(tmp_path / "c"), "--scale", "-1"]) == 2
    assert "scale must be positive" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_by_default_the_scene_chooses_the_length_within_the_cap(tmp_path):
    """No --iterations: training holds while held-out error (every 8th time step) improves, ends
    within the --minutes cap, and says why it stopped."""
    data = tmp_path / "data"
    simulate_dataset(data, SimulateConfig(frames=16, width=40, height=30, seed=1, points=300))
    res = recon("run", data, "--out", tmp_path / "run", "--minutes", 0.25, "--threads", 1)
    summary = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert summary["train_seconds"] <= 0.25 * 60 + 2
    reason = summary["stop_reason"]
    assert reason.startswith(("converged", "time cap of 0.25 min")), reason
    assert f"stopped: {reason}" in res.stdout
    events = json.loads((tmp_path / "run" / "events.json").read_text())
    assert events == {"stop_reason": reason, "events": []}
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["stop"]["converge"] and config["minutes"] == 0.25


def test_windows_coarse_to_fine_and_scale_bound_from_the_command_line(run, tmp_path):
    data, _ = run
    recon("run", data, "--out", tmp_path / "r", "--iterations", 12, "--threads", 1, "--crop", 0.5,
          "--coarse-to-fine", 1, "--max-scale", 0.3)
    config = json.loads((tmp_path / "r" / "config.json").read_text())
    assert config["crop"] == 0.5 and config["resolution"] == [[0.0, 2], [config["stop"]["hold_at"], 1]]
    assert config["densify"]["max_scale"] == 0.3
    res = recon("run", data, "--out", tmp_path / "bad", "--crop", 1.5, check=False)
    assert res.returncode == 2 and "--crop: must be at most 1, got 1.5" in res.stderr
