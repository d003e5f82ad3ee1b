"""The status server's endpoints over real sockets, against what a publisher and `rig capture` wrote."""
import http.client
import json
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import server
from recon.live.publish import LivePublisher
from rig.info import session_info
from rig.session import open_session
from server.run_reader import parse_jsonl


def capture(out, seconds=2):
    """A real short `rig capture` of the simulated rig (synthetic scene: quick to render)."""
    subprocess.run([sys.executable, "-m", "rig", "capture", "--duration", str(seconds), "--out", str(out),
                    "--sim-scene", "synthetic", "--quiet"], check=True, capture_output=True, timeout=120)
    return out


def get(handle, path, method="GET"):
    conn = http.client.HTTPConnection(handle.host, handle.port, timeout=10)
    try:
        conn.request(method, path)
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def get_json(handle, path):
    status, headers, body = get(handle, path)
    assert headers["content-type"] == "application/json" and headers["cache-control"] == "no-store"
    return status, json.loads(body)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return capture(tmp_path_factory.mktemp("srv_session") / "s")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A run folder as a trainer would leave it mid-training."""
    run = tmp_path_factory.mktemp("srv_run")
    pub = LivePublisher(run)
    for i in range(30):
        pub.metric({"iteration": 10 * i, "loss_rgb": 0.2 / (i + 1), "psnr_rgb": 15.0 + i / 3,
                    "gaussians": 1000 + i, "roles": {"shared": 900, "rgb": 50 + i, "thermal": 50}})
    pub.status({"state": "training", "method": "dtg", "iteration": 290, "progress": 0.29,
                "roles": {"shared": 900, "rgb": 79, "thermal": 50}, "gaussians": 1029})
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    kelvin = 295 + 30 * rng.random((24, 32))
    pub.renders(1.0, rgb, kelvin, 290.0, 330.0, iteration=290)
    pub.renders(0.0, rgb, kelvin, 290.0, 330.0, slot=0, iteration=290)
    return run


@pytest.fixture(scope="module")
def handle(run, session):
    h = server.serve("127.0.0.1", 0, run_dir=run, session_dir=session, session_poll_s=0.1)
    deadline = time.monotonic() + 20
    while get(h, "/api/capture")[0] != 200 and time.monotonic() < deadline:
        time.sleep(0.1)
    yield h
    h.stop()


def test_status_is_what_the_trainer_published(handle, run):
    status, body = get_json(handle, "/api/status")
    published = json.loads((run / "live" / "status.json").read_text())
    assert status == 200 and body.pop("age_s") >= 0
    assert body == published


def test_metrics_are_decimated_keeping_first_and_last(handle, run):
    lines = parse_jsonl((run / "live" / "metrics.jsonl").read_bytes())
    status, body = get_json(handle, "/api/metrics?max=5")
    assert status == 200 and body["total"] == 30 and len(body["points"]) == 5
    assert body["points"][0] == lines[0] and body["points"][-1] == lines[-1]
    assert get_json(handle, "/api/metrics")[1]["points"] == lines           # default max 500 > 30
    for bad in ("max=1", "max=abc", "max=99999"):
        assert get_json(handle, f"/api/metrics?{bad}")[0] == 400


def test_gaussians_per_role(handle):
    status, body = get_json(handle, "/api/gaussians?max=10")
    assert status == 200 and body["roles"] == {"shared": 900, "rgb": 79, "thermal": 50} and body["gaussians"] == 1029
    assert len(body["history"]) == 10 and body["history"][-1]["roles"]["rgb"] == 79


def test_render_index_and_files(handle, run):
    status, index = get_json(handle, "/api/renders")
    assert status == 200 and sorted(index["sets"]) == ["latest", "t00"]
    live = run / "live" / "render"
    for path, ctype in [("latest/rgb.png", "image/png"), ("latest/thermal.png", "image/png"),
                        ("t00/kelvin.npy", "application/octet-stream")]:
        status, headers, body = get(handle, f"/render/{path}?v=3")
        assert status == 200 and headers["content-type"] == ctype and headers["cache-control"] == "no-store"
        assert body == (live / path).read_bytes()
    assert get(handle, "/render/t05/rgb.png")[0] == 503          # a slot not published (yet)
    assert get(handle, "/render/t5/rgb.png")[0] == 404           # a name that can never exist


def test_capture_and_sync_agree_with_rig_info(handle, session):
    info = session_info(open_session(session))
    status, cap = get_json(handle, "/api/capture")
    assert status == 200 and cap["state"] == "closed" and cap["closed"] is True
    assert cap["streams"] == info["streams"] and cap["duration_s"] == info["duration_s"]
    assert cap["streams"]["thermal"]["frames"] > 30 and cap["pairs"] == info["pairs"]
    status, sync = get_json(handle, "/api/sync")
    assert status == 200 and sync["residual_ms"] == info["sync_residual_ms"]
    assert sync["method"] == info["sync"]["method"] and sync["files"] == info["sync"]["files"]


def test_page_is_self_contained(handle):
    status, headers, body = get(handle, "/")
    assert status == 200 and headers["content-type"] == "text/html; charset=utf-8"
    assert "default-src 'none'" in headers["content-security-policy"]
    page = body.decode()
    # nothing loaded from elsewhere: every src/href is local or inline data
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", page)
    assert refs and all(r.startswith(("/", "data:", "#")) for r in refs), refs
    assert not re.search(r"https?://", page) and "@import" not in page


def test_head_sends_headers_only(handle):
    _, headers, body = get(handle, "/api/status")
    status, head_headers, head_body = get(handle, "/api/status", "HEAD")
    assert status == 200 and head_body == b""
    assert abs(int(head_headers["content-length"]) - len(body)) <= 4      # age_s may have grown a digit


def test_config_names_the_folders(handle, run, session):
    assert get_json(handle, "/api/config")[1] == {"run": str(run), "session": str(session)}
    assert get_json(handle, "/api/nothing")[0] == 404


def test_nothing_published_yet_is_503_then_fills_in(tmp_path, session):
    run, later = tmp_path / "run", tmp_path / "session"
    with server.serve("127.0.0.1", 0, run_dir=run, session_dir=later, session_poll_s=0.05) as h:
        for path in ("/api/status", "/api/metrics", "/api/gaussians", "/api/renders", "/api/capture", "/api/sync"):
            status, headers, body = get(h, path)
            assert (status, json.loads(body)) == (503, {}), path
            assert headers["retry-after"] == "1"
        assert get(h, "/render/latest/rgb.png")[0] == 503
        LivePublisher(run).status({"state": "starting", "iteration": 0})
        assert get_json(h, "/api/status")[1]["state"] == "starting"
        shutil.copytree(session, later)           # the capture starts after the server
        deadline = time.monotonic() + 10
        while get(h, "/api/capture")[0] != 200:
            assert time.monotonic() < deadline, "the session monitor never picked the session up"
            time.sleep(0.05)


def test_without_a_run_or_session_those_endpoints_stay_503(tmp_path):
    with server.serve(port=0) as h:
        assert h.host == "127.0.0.1" and h.url == f"http://127.0.0.1:{h.port}/"   # localhost unless told
        assert get(h, "/api/status")[0] == 503 and get(h, "/api/capture")[0] == 503
        assert get(h, "/render/latest/thermal.png")[0] == 503
        assert get(h, "/")[0] == 200
        with pytest.raises(OSError):
            server.serve("127.0.0.1", h.port)                  # the port is taken: a clear error
    with pytest.raises(OSError):
        get(h, "/")                                             # stopped means stopped


def interruptible() -> None:
    """In the server's process before exec: Ctrl-C (SIGINT) at its default, as in a terminal. A suite
    started as a background job (`make test &`) has SIGINT ignored, and children inherit that."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_cli_serves_until_interrupted(tmp_path, run):
    proc = subprocess.Popen([sys.executable, "-m", "server", "--run", str(run), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=interruptible)
    try:
        line = proc.stdout.readline()
        m = re.match(r"status page: http://127\.0\.0\.1:(\d+)/", line)
        assert m, line
        conn = http.client.HTTPConnection("127.0.0.1", int(m.group(1)), timeout=10)
        conn.request("GET", "/api/status")
        assert json.loads(conn.getresponse().read())["iteration"] == 290
        conn.close()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    bad = subprocess.run([sys.executable, "-m", "server"], capture_output=True, text=True)
    assert bad.returncode == 2 and "give --run RUN, --session SESSION or both" in bad.stderr
