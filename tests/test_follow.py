"""Live training (`recon run SESSION --follow`): the time embedding grows without forgetting, the
re-solved reconstructions stay in one world frame, and a real simulated capture is followed to
a finished run while it is still being written."""
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.follow import align_dataset, similarity
from recon.render import render_frame
from recon.scene import Scene
from recon.time_embedding import TimeEmbedding
from recon.train import Trainer

ROOT = Path(__file__).resolve().parents[1]


def test_extended_time_embedding_keeps_every_learned_time():
    torch.manual_seed(0)
    te = TimeEmbedding(16, rows_coarse=4, rows_fine=9)
    with torch.no_grad():
        te.coarse.normal_()
        te.fine.normal_()
    new = te.extended(2)
    assert new["coarse"].shape[0] == 7 and new["fine"].shape[0] == 17
    grown = TimeEmbedding(16, 7, 17)
    with torch.no_grad():
        grown.coarse.copy_(new["coarse"])
        grown.fine.copy_(new["fine"])
    for t in np.linspace(0, 1, 23):
        assert torch.allclose(te(float(t)), grown(float(t) / 2), atol=1e-6), t
    # the new half starts where the old span ended (no jump at the old horizon)
    assert torch.allclose(grown(0.75), te(1.0), atol=1e-6)


def test_trainer_extend_time_keeps_renders_and_trains_on(tmp_path):
    out = tmp_path / "d"
    simulate_dataset(out, SimulateConfig(frames=4, width=40, height=30, seed=1, points=400))
    scene = Scene(load_dataset(out))
    cfg = make_config("dtg", iterations=40, eval_every=1000, log_every=1000, checkpoint_every=10_000)
    tr = Trainer(cfg, scene, log=lambda _: None)
    tr.progress_fn = lambda _: 0.9          # past coarse-to-fine: lookups are exact row interpolation
    for _ in range(15):
        tr.step()
    cam = scene.test["thermal"][0].camera
    before = [render_frame(tr.model, "thermal", t, cam) for t in (0.0, 0.4, 1.0)]
    rows = tr.model.time_embedding.fine.shape[0]
    tr.extend_time(2)
    assert tr.model.time_embedding.fine.shape[0] == 2 * rows - 1
    after = [render_frame(tr.model, "thermal", t / 2, cam) for t in (0.0, 0.4, 1.0)]
    for a, b in zip(before, after):
        assert torch.allclose(a, b, atol=1e-5)
    te_param = tr.model.time_embedding.fine
    assert any(p is te_param for g in tr.optimizer.param_groups for p in g["params"])
    tr.step()                               # Adam state padded to the new rows: no shape error
    assert tr.optimizer.state[te_param]["exp_avg"].shape == te_param.shape


def test_similarity_alignment_undoes_a_resolved_frame(tmp_path):
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    r = q * np.sign(np.linalg.det(q))
    dst = 2.5 * src @ r.T + np.array([1.0, -2.0, 0.5])
    s, r_est, t = similarity(src, dst)
    assert s == pytest.approx(2.5) and np.allclose(r_est, r) and np.allclose(t, [1.0, -2.0, 0.5])

    # a re-run of SfM returns the same cameras in another frame: align_dataset maps them back
    out = tmp_path / "d"
    simulate_dataset(out, SimulateConfig(frames=6, width=32, height=24, seed=2, points=100))
    meta = json.loads((out / "transforms.json").read_text())
    meta["frames"] = [f for f in meta["frames"] if f["camera"] == "cam0"]   # one rig, as a session
    rgb = sorted(((f["timestamp_s"], np.asarray(f["transform_matrix"])) for f in meta["frames"]
                  if f["modality"] == "rgb"), key=lambda tm: tm[0])
    reference = (np.array([t for t, _ in rgb]), np.stack([m[:3, 3] for _, m in rgb]))
    for f in meta["frames"]:
        m = np.asarray(f["transform_matrix"])
        m[:3, :3] = r.T @ m[:3, :3]
        m[:3, 3] = (r.T @ (m[:3, 3] - 0.3)) / 1.7
        f["transform_matrix"] = m.tolist()
    (out / "transforms.json").write_text(json.dumps(meta))
    times, centres = align_dataset(out, reference)
    assert np.allclose(centres, reference[1], atol=1e-6)
    back = json.loads((out / "transforms.json").read_text())
    first = next(f for f in back["frames"] if f["modality"] == "rgb" and f["timestamp_s"] == rgb[0][0])
    assert np.allclose(np.asarray(first["transform_matrix"]), rgb[0][1], atol=1e-6)


def test_follow_trains_while_a_simulated_capture_is_written(tmp_path):
    """`rig capture` (simulated rig, own process) and `recon run --follow` side by side: the first
    poses come from a capture still running, training runs before it ends, and the run finishes
    like `recon run` (renders, metrics, export)."""
    session, run = tmp_path / "session", tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with open(tmp_path / "capture.log", "w") as capture_log:
        capture = subprocess.Popen([sys.executable, "-m", "rig", "capture", "--duration", "20",
                                    "--out", str(session), "--quiet"], env=env, cwd=ROOT,
                                   stdout=subprocess.DEVNULL, stderr=capture_log)
        try:
            while not (session / "session.json").exists():
                assert capture.poll() is None, (tmp_path / "capture.log").read_text()
                time.sleep(0.1)
            follow = subprocess.run([sys.executable, "-m", "recon", "run", str(session), "--follow",
                                     "--after", "60", "--out", str(run)],
                                    env=env, cwd=ROOT, capture_output=True, text=True, timeout=400)
        finally:
            capture.wait(timeout=120)
    assert capture.returncode == 0, (tmp_path / "capture.log").read_text()
    log = follow.stdout + follow.stderr
    assert follow.returncode == 0, log[-4000:]
    first = next(line for line in log.splitlines() if "live poses: v0 " in line)
    assert "(final)" not in first, log[-4000:]                # poses from a capture still being written
    finished = int(log.split("capture finished at iteration ")[1].split(";")[0])
    assert finished > 0                                   # trained while capturing
    assert len(list((run / "live_data").glob("v*"))) >= 2   # re-solved as the capture grew
    summary = json.loads((run / "metrics.json").read_text())
    assert summary["iterations"] >= finished + 60
    assert {"rgb", "thermal"} <= set(summary["metrics"]), summary
    assert any((run / "renders").rglob("*.png")) and (run / "export" / "model.ply").exists()
