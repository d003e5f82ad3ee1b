"""`rig capture --serve` and `recon run --serve` start the status page themselves: each CLI, run as
a real process on an ephemeral port, prints the page's URL and answers while it works."""
import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

from recon.data.simulate import SimulateConfig, simulate_dataset

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


def _url_of(proc: subprocess.Popen, timeout: float = 60.0) -> str:
    """The URL the CLI printed ("status page: http://...")."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("status page: "):
            return line.split("status page: ", 1)[1].strip()
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no 'status page:' line (exit {proc.poll()})")


def _get_json(url: str) -> tuple[int, dict]:
    try:
        with urllib.request.urlopen(url, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, {}


def _poll(url: str, ok, timeout: float) -> dict:
    deadline, last = time.monotonic() + timeout, None
    while time.monotonic() < deadline:
        code, body = _get_json(url)
        last = (code, body)
        if code == 200 and ok(body):
            return body
        time.sleep(0.2)
    raise AssertionError(f"{url}: never satisfied; last reply {last}")


def test_rig_capture_serve_shows_the_capture(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "rig", "capture", "--duration", "6", "--out", str(tmp_path / "s"),
                             "--serve", "--port", "0", "--quiet"], cwd=ROOT, env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        url = _url_of(proc)
        assert url.startswith("http://127.0.0.1:")            # localhost unless --host is given
        body = _poll(url + "api/capture", lambda b: (b.get("streams", {}).get("thermal", {}).get("complete") or 0) > 0, 60)
        assert body["state"] in ("recording", "closed")
        with urllib.request.urlopen(url, timeout=5) as page:
            assert b"<html" in page.read().lower()
    finally:
        proc.wait(timeout=120)
    assert proc.returncode == 0


def test_recon_run_serve_shows_training(tmp_path):
    data = tmp_path / "d"
    simulate_dataset(data, SimulateConfig(frames=4, width=48, height=36, seed=0, points=300))
    proc = subprocess.Popen([sys.executable, "-m", "recon", "run", str(data), "--out", str(tmp_path / "run"),
                             "--iterations", "200", "--serve", "--port", "0"], cwd=ROOT, env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        url = _url_of(proc)
        status = _poll(url + "api/status", lambda b: (b.get("iteration") or 0) > 0, 120)
        assert status["method"] == "dtg"
        renders = _poll(url + "api/renders", lambda b: "latest" in json.dumps(b), 60)
        assert "rgb" in json.dumps(renders) and "thermal" in json.dumps(renders)
    finally:
        proc.wait(timeout=300)
    assert proc.returncode == 0
