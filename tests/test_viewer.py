"""`recon view`: the render endpoint equals recon.render at the same pose and time, the coalescing
drops stale requests, the point-over-time series equals temperature renders at those times, the
live service snapshots a training model without touching its randomness, and the CLI's errors.
One tiny `recon run` (as tests/test_run_cli.py) shared by the module (~15 s)."""
import http.client
import json
import subprocess
import sys
import threading
import time
from urllib.parse import urlsplit

import numpy as np
import pytest
import torch

import server
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.render import load_run, render_frame
from recon.view import LiveRenderService, RenderService
from server.viewer import unpack_render


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    data, out = root / "data", root / "run"
    simulate_dataset(data, SimulateConfig(frames=4, width=40, height=30, seed=1, points=300))
    subprocess.run([sys.executable, "-m", "recon", "run", str(data), "--out", str(out), "--iterations", "20",
                    "--threads", "1"], check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def served(run):
    service = RenderService.from_run(run)
    with server.serve("127.0.0.1", 0, run_dir=run, renderer=service) as handle:
        yield handle, service


def get(handle, target: str):
    u = urlsplit(handle.url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
    try:
        conn.request("GET", target)
        r = conn.getresponse()
        return r.status, r.getheader("Content-Type"), r.read()
    finally:
        conn.close()


def nudged_pose(run, dx=0.03, yaw=0.15) -> np.ndarray:
    """The run's default camera, moved and turned a little: a pose no training camera had."""
    c2w = np.asarray(json.loads((run / "scene.json").read_text())["camera"]["c2w"])
    c, s = np.cos(yaw), np.sin(yaw)
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    out = c2w.copy()
    out[:3, :3] = c2w[:3, :3] @ turn
    out[:3, 3] += dx
    return out


def query(c2w, t, size="48x36", client="t", extra=""):
    return f"c2w={','.join(repr(float(v)) for v in np.asarray(c2w).ravel())}&t={t}&size={size}&client={client}{extra}"


def reference_kelvin(run, c2w, t, camera: dict, tmp_path) -> np.ndarray:
    """What recon.render produces (the code behind `recon render`) at that pose, time and intrinsics."""
    model, facts = load_run(run)
    (tmp_path / "pose.json").write_text(json.dumps(np.asarray(c2w).tolist()))
    args = type("A", (), {"pose": str(tmp_path / "pose.json"), **camera})()
    from recon.render import camera_from_args
    cam = camera_from_args(args, facts)
    k_min, k_max = facts["thermal_range_k"]
    return (render_frame(model, "thermal", t, cam)[..., 0] * (k_max - k_min) + k_min).numpy()


def test_render_endpoint_equals_recon_render(run, served, tmp_path):
    handle, _ = served
    c2w = nudged_pose(run)
    status, ctype, body = get(handle, "/api/view/render?" + query(c2w, 0.37))
    assert status == 200 and ctype == "application/octet-stream"
    header, arrays = unpack_render(body)
    assert header["t"] == 0.37 and np.allclose(header["c2w"], c2w) and (header["width"], header["height"]) == (48, 36)
    assert arrays["rgb"].shape == (36, 48, 3) and arrays["kelvin"].shape == (36, 48)
    ref = reference_kelvin(run, c2w, 0.37, header["camera"], tmp_path)
    assert np.abs(arrays["kelvin"] - ref).max() < 0.1
    # a different time is a different picture (the model is dynamic), same pose
    _, _, other = get(handle, "/api/view/render?" + query(c2w, 0.9))
    assert not np.array_equal(unpack_render(other)[1]["kelvin"], arrays["kelvin"])


def test_info_page_and_refusals(run, served):
    handle, _ = served
    status, _, body = get(handle, "/api/view/info")
    info = json.loads(body)
    assert status == 200 and info["source"] == "run" and info["time_range"] == [0.0, 1.0]
    assert len(info["cameras"]) > 1 and len(info["colour_maps"]["ironbow"]) == 256 and len(info["center"]) == 3
    status, ctype, page = get(handle, "/view")
    assert status == 200 and ctype.startswith("text/html") and b"api/view/render" in page
    assert json.loads(get(handle, "/api/config")[2])["viewer"] is True
    c2w = nudged_pose(run)
    for bad in (query(c2w, 1.5), query(c2w, 0.5, size="5000x10"), query(c2w, 0.5, client="a%20b"),
                "c2w=1,2,3&t=0.5", query(np.full((4, 4), np.nan), 0.5), query(c2w, 0.5, extra="&px=999,0"),
                query(c2w, 0.5, extra="&px=1,1&n=100000")):
        path = "/api/view/series?" if "px=" in bad else "/api/view/render?"
        status, _, body = get(handle, path + bad)
        assert status == 400 and json.loads(body)["error"], bad
    with server.serve("127.0.0.1", 0, run_dir=run) as plain:       # no renderer: no viewer
        assert get(plain, "/view")[0] == 404 and get(plain, "/api/view/info")[0] == 404
        assert "viewer" not in json.loads(get(plain, "/api/config")[2])


def test_coalescing_drops_stale_requests(run, served):
    handle, service = served
    real = service.render

    def slowed(*a, **k):           # a render that takes a while, so a burst piles up behind it
        time.sleep(0.15)
        return real(*a, **k)

    service.render = slowed
    before = handle.viewer_counts
    results, n = [None] * 12, 12

    def ask(i):
        results[i] = get(handle, "/api/view/render?" + query(nudged_pose(run, dx=0.002 * i), 0.5, client="burst"))

    try:
        threads = []
        for i in range(n):
            threads.append(threading.Thread(target=ask, args=(i,)))
            threads[-1].start()
            time.sleep(0.01)
        for t in threads:
            t.join(60)
    finally:
        service.render = real
    after = handle.viewer_counts
    rendered = after["rendered"] - before["rendered"]
    assert all(r[0] == 200 for r in results)
    assert rendered <= n // 2, after
    assert after["superseded"] - before["superseded"] >= n - rendered
    # every reply is the newest pose known when it was rendered: the last request got its own pose
    last = unpack_render(results[-1][2])[0]
    assert np.allclose(last["c2w"], nudged_pose(run, dx=0.002 * (n - 1)))


def test_series_equals_renders_at_those_times(run, served):
    handle, service = served
    c2w = nudged_pose(run, dx=0.0, yaw=0.0)
    _, _, body = get(handle, "/api/view/render?" + query(c2w, 0.4))
    header, arrays = unpack_render(body)
    x, y = 24, 18                  # the image centre: the simulated object
    status, _, body = get(handle, "/api/view/series?" + query(c2w, 0.4, extra=f"&px={x},{y}&n=6"))
    assert status == 200, body
    series = json.loads(body)
    assert len(series["samples"]) == 6 and series["pixel"] == [x, y] and len(series["followed"]) >= 1
    model, facts = load_run(run)
    k_min, k_max = facts["thermal_range_k"]
    cam, _ = service.camera(c2w, 48, 36)
    inside = [s for s in series["samples"] if s["kelvin"] is not None]
    assert len(inside) >= 3
    for s in inside:
        ref = render_frame(model, "thermal", s["time"], cam)[..., 0] * (k_max - k_min) + k_min
        assert abs(float(ref[s["y"], s["x"]]) - s["kelvin"]) < 0.1, s
    # at the picked time the followed point is where it was picked
    at_t = service.series(c2w, 0.4, 48, 36, x, y, times=[0.4])["samples"][0]
    assert (at_t["x"], at_t["y"]) == (x, y) and at_t["visible"]
    assert abs(at_t["kelvin"] - float(arrays["kelvin"][y, x])) < 0.1


def test_live_service_snapshots_without_touching_training(tmp_path):
    from recon.config import make_config
    from recon.data import load_dataset
    from recon.scene import Scene
    from recon.train.trainer import Trainer

    simulate_dataset(tmp_path / "d", SimulateConfig(frames=4, width=40, height=30, seed=2, points=300))

    def trainer():
        torch.manual_seed(0)
        cfg = make_config("dtg", iterations=10**6, eval_every=10**9, log_every=10**9, checkpoint_every=10**9, seed=0)
        return Trainer(cfg, Scene(load_dataset(tmp_path / "d")), log=lambda _: None)

    before = torch.get_num_threads()
    torch.set_num_threads(1)         # bit-reproducible training (as tests/test_publish.py)
    try:
        bare, served_t = trainer(), trainer()
        live = LiveRenderService(refresh_s=0.0, inline=False)
        for i in range(6):
            bare.step()
            served_t.step()
            live.on_step(served_t)
            if i % 2 == 0:               # a render asks for a fresh copy; the next step hands it over
                out = live.render(np.asarray(live.cameras[0]["c2w"]), 0.5, 40, 30)
                assert out["kelvin"].shape == (30, 40)
    finally:
        torch.set_num_threads(before)
    assert live.snapshots >= 3
    # snapshots draw no training randomness and change no parameter
    assert torch.equal(bare.gen.get_state(), served_t.gen.get_state())
    for k, v in bare.model.state_dict().items():
        assert torch.equal(v, served_t.model.state_dict()[k]), k
    info = live.info()
    assert info["source"] == "live" and info["gaussians"] == served_t.model.num_gaussians

    # inline: a request is rendered by the training thread itself, between two of its steps
    live = LiveRenderService()
    stop = threading.Event()

    def loop():
        while not stop.is_set():
            live.on_step(served_t, served_t.step())

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        while live.snapshots == 0:
            time.sleep(0.01)
        for _ in range(3):
            assert live.render(np.asarray(live.cameras[0]["c2w"]), 0.25, 40, 30)["kelvin"].shape == (30, 40)
    finally:
        stop.set()
        thread.join(30)
    assert live.inline_renders == 3


def test_cli_errors(tmp_path):
    res = subprocess.run([sys.executable, "-m", "recon", "view", str(tmp_path)], capture_output=True, text=True)
    assert res.returncode == 2 and str(tmp_path) in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = subprocess.run([sys.executable, "-m", "recon", "view", str(tmp_path), "--size", "3x3"],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "size" in res.stderr
