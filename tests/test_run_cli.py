"""`recon run` / `recon render` end to end on a tiny simulated dataset."""
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.splat.ply import read_gaussians_ply


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
    assert set(summary["metrics"]) == {"rgb", "thermal"}
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
    assert res.returncode != 0 and "neither a prepared dataset (transforms.json) nor a rig session" in res.stderr
    res = recon("render", tmp_path, check=False)
    assert res.returncode != 0 and "missing" in res.stderr
