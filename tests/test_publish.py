"""recon.live.publish: the RUN/live/ contract the status server reads, and the trainer feed."""
import io
import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.live.publish import KELVIN_SCALE, LivePublisher, TrainingFeed, thin
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.viz import thermal_image
from server.run_reader import parse_jsonl


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_publish")
    simulate_dataset(out, SimulateConfig(variant="default", frames=6, width=48, height=36, seed=3, points=600))
    return Scene(load_dataset(out))


def trainer(scene, iterations=60):
    cfg = make_config("dtg", iterations=iterations, eval_every=10**6, log_every=10**6, checkpoint_every=10**6)
    cfg.densify.every = 20
    cfg.loss.embedding_knn_sample = 256
    return Trainer(cfg, scene, log=lambda _: None)


def test_status_is_replaced_whole_and_never_holds_nan(tmp_path):
    pub = LivePublisher(tmp_path)
    pub.status({"state": "training", "iteration": 3, "psnr": {"rgb": float("nan")}, "its": np.float32(2.5),
                "loss": torch.tensor(0.25)})
    pub.status({"state": "training", "iteration": 4})
    text = (tmp_path / "live" / "status.json").read_text()
    s = json.loads(text)                      # strict JSON: NaN would have been written as NaN
    assert "NaN" not in text and s["iteration"] == 4 and "psnr" not in s
    assert s["format"] == "thermal4d-live" and s["version"] == 1 and s["wall_s"] >= 0
    pub.status({"iteration": 5, "psnr": {"rgb": float("nan"), "thermal": 20.0}, "its": np.float32(2.5)})
    s = json.loads((tmp_path / "live" / "status.json").read_text())
    assert s["psnr"] == {"rgb": None, "thermal": 20.0} and s["its"] == 2.5
    assert not [p for p in (tmp_path / "live").iterdir() if p.name.endswith(".tmp")]
    with pytest.raises(TypeError):
        pub.status({"bad": object()})


def test_metric_history_stays_bounded_and_spans_the_run(tmp_path):
    pub = LivePublisher(tmp_path, max_lines=40)
    for i in range(500):
        pub.metric({"iteration": i})
        lines = (tmp_path / "live" / "metrics.jsonl").read_bytes().splitlines()
        assert len(lines) <= 40
    its = [p["iteration"] for p in parse_jsonl((tmp_path / "live" / "metrics.jsonl").read_bytes())]
    assert its[0] == 0 and its[-1] == 499 and its == sorted(its)
    assert its[-10:] == list(range(490, 500))        # the newest points are kept whole
    # a new publisher on the same run goes on counting the lines already there
    pub2 = LivePublisher(tmp_path, max_lines=40)
    for i in range(500, 600):
        pub2.metric({"iteration": i})
    assert len((tmp_path / "live" / "metrics.jsonl").read_bytes().splitlines()) <= 40


def test_thin_keeps_recent_and_halves_the_rest():
    assert thin(list(range(10)), 4) == [0, 2, 4, 6, 7, 8, 9]
    assert thin(list(range(3)), 4) == [0, 1, 2]


def test_a_torn_last_line_is_skipped_by_readers(tmp_path):
    pub = LivePublisher(tmp_path)
    pub.metric({"iteration": 1})
    with open(tmp_path / "live" / "metrics.jsonl", "ab") as f:
        f.write(b'{"iteration": 2, "loss')            # a writer caught mid-line
    assert [p["iteration"] for p in parse_jsonl((tmp_path / "live" / "metrics.jsonl").read_bytes())] == [1]


def test_renders_write_pngs_kelvin_and_an_index(tmp_path):
    pub = LivePublisher(tmp_path)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    kelvin = 290 + 40 * rng.random((30, 40))
    kelvin[0, 0] = np.nan
    assert pub.renders(0.75, rgb, kelvin, 280.0, 340.0, iteration=12, timestamp_s=7.5) == "latest"
    assert pub.renders(0.25, rgb, None, 280.0, 340.0, slot=3) == "t03"
    root = tmp_path / "live"
    index = json.loads((root / "renders.json").read_text())
    latest, slot = index["sets"]["latest"], index["sets"]["t03"]
    assert (latest["time"], latest["iteration"], latest["timestamp_s"]) == (0.75, 12, 7.5)
    assert slot["files"] == ["rgb.png"] and slot["version"] > latest["version"] == 1
    assert index["vmin_k"] == 280.0 and index["vmax_k"] == 340.0
    assert np.array_equal(np.asarray(Image.open(root / "render/latest/rgb.png")), rgb)
    picture = np.asarray(Image.open(root / "render/latest/thermal.png").convert("RGB"))
    assert np.array_equal(picture, thermal_image(kelvin, 280.0, 340.0))     # colourised with its °C bar
    x, y, w, h = latest["thermal_box"]
    assert (latest["width"], latest["height"]) == (40, 30) and w / 40 == h / 30 == int(w / 40) and x == y == 0
    assert w <= picture.shape[1] and h == picture.shape[0]
    counts = np.load(root / "render/latest/kelvin.npy")
    assert counts.dtype == np.dtype("<u2") and counts.shape == (30, 40) and counts[0, 0] == 0
    assert np.nanmax(np.abs(counts[1:, 1:] * KELVIN_SCALE - kelvin[1:, 1:])) <= KELVIN_SCALE / 2 + 1e-9


@pytest.mark.parametrize("kwargs, match", [
    ({"rgb": None, "kelvin": None}, "rgb, kelvin"),
    ({"rgb": np.zeros((4, 4), np.uint8)}, r"\(H, W, 3\) uint8"),
    ({"kelvin": np.zeros((4, 4, 1))}, r"\(H, W\)"),
    ({"slot": 64}, "slot"),
    ({"vmin_k": 300.0, "vmax_k": 300.0}, "vmin_k < vmax_k"),
])
def test_renders_rejects_bad_input(tmp_path, kwargs, match):
    args = {"rgb": np.zeros((4, 4, 3), np.uint8), "kelvin": np.full((4, 4), 300.0), "vmin_k": 290.0,
            "vmax_k": 310.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        LivePublisher(tmp_path).renders(0.5, args.pop("rgb"), args.pop("kelvin"), args.pop("vmin_k"),
                                        args.pop("vmax_k"), **args)


@pytest.fixture
def one_thread():
    """Bit-reproducible training: with several threads gradient sums vary in their last bits."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_feed_publishes_a_trainer_and_does_not_change_training(scene, tmp_path, one_thread):
    plain, fed = trainer(scene), trainer(scene)
    feed = TrainingFeed(LivePublisher(tmp_path), ring=4, status_every_s=0, metric_every_s=0,
                        psnr_every_s=0, render_every_s=0)
    for _ in range(12):
        plain.step()
        feed.on_step(fed, fed.step())
    # publishing draws no random numbers and touches no parameter: the two runs are identical
    assert torch.equal(plain.gen.get_state(), fed.gen.get_state())
    for k, p in plain.model.gaussians.items():
        assert torch.equal(p, fed.model.gaussians[k]), k
    feed.finish(fed)
    live = tmp_path / "live"
    status = json.loads((live / "status.json").read_text())
    assert status["state"] == "done" and status["iteration"] == 12 and status["method"] == "dtg"
    assert status["gaussians"] == fed.model.num_gaussians and status["roles"] == fed.counts()
    assert set(status["psnr"]) == {"rgb", "thermal"} and all(math.isfinite(v) for v in status["psnr"].values())
    assert status["psnr"] == pytest.approx(fed.holdout_psnr(), abs=1e-3)
    assert status["latest_time"] == max(scene.times) and status["time_steps"] == len(scene.times)
    lines = parse_jsonl((live / "metrics.jsonl").read_bytes())
    assert [p["iteration"] for p in lines] == list(range(1, 13)) + [12]
    assert all("loss_rgb" in p and "loss_thermal" in p for p in lines)
    index = json.loads((live / "renders.json").read_text())
    assert sorted(index["sets"]) == ["latest", "t00", "t01", "t02", "t03"]
    assert [index["sets"][f"t0{i}"]["time"] for i in range(4)] == pytest.approx(np.linspace(0, 1, 4))
    assert (index["vmin_k"], index["vmax_k"]) == (scene.k_min, scene.k_max)
    # the latest render is the model's render at the newest time step, from a camera that saw it
    counts = np.load(live / "render/latest/kelvin.npy").astype(np.float64) * KELVIN_SCALE
    view = min(scene.test["thermal"], key=lambda v: abs(v.time - max(scene.times)))
    from recon.render import render_frame
    expect = scene.kelvin(render_frame(fed.model, "thermal", max(scene.times), view.camera)[..., 0]).numpy()
    assert np.abs(counts - expect).max() <= KELVIN_SCALE
    rgb = np.asarray(Image.open(io.BytesIO((live / "render/latest/rgb.png").read_bytes())))
    assert rgb.shape == (view.camera.height, view.camera.width, 3)


def test_a_resumed_run_keeps_its_renders_and_counts_on(tmp_path):
    LivePublisher(tmp_path).renders(0.5, np.zeros((4, 4, 3), np.uint8), None, 290.0, 310.0, slot=2)
    again = LivePublisher(tmp_path)
    again.renders(1.0, np.zeros((4, 4, 3), np.uint8), None, 290.0, 310.0)
    index = json.loads((tmp_path / "live" / "renders.json").read_text())
    assert sorted(index["sets"]) == ["latest", "t02"] and index["sets"]["latest"]["version"] == 2
    (tmp_path / "live" / "renders.json").write_text("[1, 2]")          # not an index: start afresh
    LivePublisher(tmp_path).renders(1.0, np.zeros((4, 4, 3), np.uint8), None, 290.0, 310.0)
    assert json.loads((tmp_path / "live" / "renders.json").read_text())["version"] == 1


def test_status_of_live_training_has_no_fixed_budget(scene, tmp_path):
    tr = trainer(scene)
    feed = TrainingFeed(LivePublisher(tmp_path))
    feed.publish_status(tr)
    assert json.loads((tmp_path / "live" / "status.json").read_text())["iterations"] == 60
    tr.progress_fn = lambda _: 0.25          # as recon.live.follow drives it while the capture grows
    feed.publish_status(tr)
    status = json.loads((tmp_path / "live" / "status.json").read_text())
    assert status["iterations"] is None and status["minutes"] is None and status["progress"] == 0.25


def test_status_carries_divergences_and_why_training_stopped(scene, tmp_path):
    tr = trainer(scene, iterations=40)
    tr.cfg.eval_every = 20
    tr.cfg.guard.snapshot_every = 20         # a good state to return to at iteration 20
    feed = TrainingFeed(LivePublisher(tmp_path))
    while tr.iteration < 21:
        tr.tick()
    with torch.no_grad():                    # a blow-up the guard must notice
        tr.model.gaussians["means"].fill_(float("nan"))
    tr.tick()
    feed.publish_status(tr)
    status = json.loads((tmp_path / "live" / "status.json").read_text())
    assert status["events"] == tr.events and status["events"][0]["rolled_back_to"] == 20
    assert "not finite" in status["events"][0]["reason"] or "nan" in status["events"][0]["reason"]
    while not tr.done():
        tr.tick()
    feed.finish(tr)
    status = json.loads((tmp_path / "live" / "status.json").read_text())
    assert status["stop_reason"] == "budget of 40 iterations reached"
