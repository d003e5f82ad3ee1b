"""The status server on a `recon batch` folder (contract: recon/batch/__init__.py): /api/batch, one run
page per job under /job/N/, and refusal of job folders outside the batch. The batch folder is made
by hand (batch.json as the driver writes it, the running job's RUN/live/ by a real LivePublisher)."""
import argparse
import http.client
import json
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import server
from recon.live.publish import LivePublisher, atomic_write
from server.cli_options import serve_from_args
from tests.chromium import ARGS, CHROMIUM, playwright
from tests.test_server_endpoints import get, interruptible

SECRET = b"top secret: never served"
NODE = "5f3c8e2a9b1d4c7e6f0a2b3c4d5e6f708192a3b4c5d6e7f8091a2b3c"


def job(name, state, seed, **fields):
    base = {"name": name, "input": f"data/{name}", "method": "dtg", "seed": seed, "run_dir": name, "state": state,
            "attempts": 1, "node": NODE, "progress": 0.0, "iteration": 0, "error": None, "seconds": None,
            "metrics": None}
    return {**base, **fields}


JOBS = [
    job("scene-a", "done", 0, progress=1.0, iteration=3000, seconds=412.5,
        metrics={"psnr_rgb": 24.51, "psnr_thermal": 31.27, "mae_k_thermal": 0.83, "mae_k_moving": 1.9}),
    job("scene-b", "running", 1, progress=0.42, iteration=420),
    job("scene-c", "failed", 2, attempts=2, error="ValueError: no thermal frames in data/scene-c", seconds=3.1),
]


def write_batch(runs, jobs, state="running"):
    runs.mkdir(parents=True, exist_ok=True)
    counts = {k: sum(j["state"] == k for j in jobs) for k in ("queued", "running", "done", "failed")}
    now = time.time()
    batch = {"format": "thermal4d-batch", "version": 1, "state": state, "address": "local", "nodes": [NODE],
             "started_unix": now - 500, "updated_unix": now, "counts": counts, "jobs": jobs}
    atomic_write(runs / "batch.json", json.dumps(batch).encode())
    return batch


def get_json(handle, path):
    status, headers, body = get(handle, path)
    assert headers["content-type"] == "application/json"
    return status, json.loads(body)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """RUNS/ mid-batch: scene-a done (its live status says so), scene-b training, scene-c failed
    before publishing anything; a secret beside RUNS."""
    root = tmp_path_factory.mktemp("srv_batch")
    (root / "secret.txt").write_bytes(SECRET)
    runs = root / "runs"
    write_batch(runs, JOBS)
    LivePublisher(runs / "scene-a").status({"state": "done", "method": "dtg", "iteration": 3000, "progress": 1.0})
    pub = LivePublisher(runs / "scene-b")
    pub.status({"state": "training", "method": "dtg", "iteration": 420, "progress": 0.42, "gaussians": 1234,
                "roles": {"shared": 1000, "rgb": 134, "thermal": 100}})
    pub.metric({"iteration": 420, "loss_rgb": 0.05, "psnr_rgb": 20.0})
    rng = np.random.default_rng(0)
    pub.renders(0.5, rng.integers(0, 256, (12, 16, 3), dtype=np.uint8), 295 + 20 * rng.random((12, 16)),
                290.0, 320.0, iteration=420)
    (runs / "scene-c").mkdir()
    return runs


@pytest.fixture(scope="module")
def handle(runs):
    h = server.serve("127.0.0.1", 0, batch_dir=runs)
    yield h
    h.stop()


def test_api_batch_is_batch_json(handle, runs):
    status, body = get_json(handle, "/api/batch")
    assert status == 200 and 0 <= body.pop("age_s") < 60
    assert body == json.loads((runs / "batch.json").read_text())
    assert [j["name"] for j in body["jobs"]] == ["scene-a", "scene-b", "scene-c"]
    assert [j["state"] for j in body["jobs"]] == ["done", "running", "failed"]
    assert get_json(handle, "/api/config")[1] == {"run": None, "session": None, "batch": str(runs)}
    assert get_json(handle, "/api/status")[0] == 503          # no run of its own at the root


def test_a_jobs_run_api_reads_that_jobs_run_folder(handle, runs):
    status, body = get_json(handle, "/job/1/api/status")
    assert status == 200 and body["iteration"] == 420 and body["state"] == "training"
    assert get_json(handle, "/job/0/api/status")[1]["state"] == "done"
    assert get_json(handle, "/job/2/api/status")[0] == 503                  # failed before publishing
    assert get_json(handle, "/job/1/api/gaussians")[1]["gaussians"] == 1234
    assert get_json(handle, "/job/1/api/metrics")[1]["total"] == 1
    assert sorted(get_json(handle, "/job/1/api/renders")[1]["sets"]) == ["latest"]
    config = get_json(handle, "/job/1/api/config")[1]
    assert config == {"run": str((runs / "scene-b").resolve()), "session": None,
                      "job": {"index": 1, "name": "scene-b", "state": "running"}}
    status, headers, body = get(handle, "/job/1/render/latest/rgb.png?v=1")
    assert status == 200 and headers["content-type"] == "image/png"
    assert body == (runs / "scene-b" / "live" / "render" / "latest" / "rgb.png").read_bytes()
    assert get(handle, "/job/0/render/latest/rgb.png")[0] == 503
    assert get(handle, "/job/1/render/t5/rgb.png")[0] == 404
    assert get_json(handle, "/job/1/api/batch")[0] == 503                   # the batch is the root's


def test_a_job_page_is_the_run_page_and_needs_its_slash(handle):
    root = get(handle, "/")
    status, headers, body = get(handle, "/job/1/")
    assert status == 200 and body == root[2] and "default-src 'none'" in headers["content-security-policy"]
    assert get(handle, "/job/1/index.html")[2] == root[2]
    status, headers, _ = get(handle, "/job/1")
    assert status == 301 and headers["location"] == "/job/1/"
    # the page asks relative URLs, so under /job/N/ it reads job N's run
    assert 'getJSON("api/status")' in body.decode() and 'getJSON("/api/' not in body.decode()


@pytest.mark.parametrize("path", ["/job/3/", "/job/3/api/status", "/job/999999/api/status", "/job/1000000/",
                                  "/job/01/api/status", "/job/-1/api/status", "/job/x/api/status",
                                  "/job/1/job/0/api/status", "/job/1/live/status.json", "/job/1/api/nothing",
                                  "/job//api/status", "/job/"])
def test_job_paths_that_name_no_job_are_404(handle, path):
    status, body = get_json(handle, path)
    assert status == 404 and "error" in body


def test_traversal_under_a_job_is_refused(handle):
    for path in ("/job/1/../../secret.txt", "/job/1/%2e%2e/%2e%2e/secret.txt", "/job/../secret.txt",
                 "/job/1/render/latest/..%2f..%2f..%2fstatus.json"):
        status, _, body = get(handle, path)
        assert status in (400, 404) and SECRET not in body, path


@pytest.mark.parametrize("run_dir", ["../x", "../../x", "scene/../../x", ".", "", "/etc", None, 7, "a\x00b", "link"])
def test_a_run_dir_outside_the_batch_is_refused(tmp_path, run_dir):
    runs = tmp_path / "runs"
    LivePublisher(tmp_path / "x").status({"state": "training", "secret": SECRET.decode()})
    runs.mkdir()
    (runs / "link").symlink_to(tmp_path / "x")             # a symlink out of RUNS counts as outside
    write_batch(runs, [job("bad", "running", 0, run_dir=run_dir), job("ok", "queued", 1)])
    with server.serve("127.0.0.1", 0, batch_dir=runs) as h:
        assert get_json(h, "/api/batch")[0] == 200                         # the table still shows
        for path in ("/job/0/", "/job/0/api/status", "/job/0/api/config", "/job/0/render/latest/rgb.png"):
            status, _, body = get(h, path)
            assert status == 403 and SECRET not in body, (path, status)
            assert "error" in json.loads(body)
        assert get_json(h, "/job/1/api/status")[0] == 503                 # the others are unaffected


def test_before_batch_json_exists_503_then_fills_in_and_follows_rewrites(tmp_path):
    runs = tmp_path / "runs"
    with server.serve("127.0.0.1", 0, batch_dir=runs) as h:
        for path in ("/api/batch", "/job/0/", "/job/0/api/status"):
            status, headers, body = get(h, path)
            assert (status, json.loads(body), headers["retry-after"]) == (503, {}, "1"), path
        write_batch(runs, JOBS[:1])
        assert get_json(h, "/api/batch")[1]["jobs"][0]["name"] == "scene-a"
        assert get_json(h, "/job/1/api/status")[0] == 404
        write_batch(runs, JOBS, state="done")                                # replaced whole: re-read
        body = get_json(h, "/api/batch")[1]
        assert body["state"] == "done" and len(body["jobs"]) == 3
        assert get_json(h, "/job/1/api/status")[0] == 503                   # scene-b not published here
        (runs / "batch.json").write_text("{ torn")
        assert get_json(h, "/api/batch")[0] == 503


def test_an_oversized_batch_json_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr("server.batch_reader.MAX_BATCH_BYTES", 2000)
    runs = tmp_path / "runs"
    write_batch(runs, JOBS[:1])
    with server.serve("127.0.0.1", 0, batch_dir=runs) as h:
        assert get_json(h, "/api/batch")[0] == 200
        write_batch(runs, [job(f"j{i}", "queued", i) for i in range(40)])
        assert get_json(h, "/api/batch")[0] == 503


def test_without_a_batch_job_pages_do_not_exist(tmp_path):
    with server.serve("127.0.0.1", 0, run_dir=tmp_path / "run") as h:
        assert get_json(h, "/job/0/api/status")[0] == 404
        assert get_json(h, "/api/batch")[0] == 503
        assert get_json(h, "/api/config")[1] == {"run": str(tmp_path / "run"), "session": None}


def test_serve_from_args_passes_the_batch_folder(runs, capsys):
    args = argparse.Namespace(serve=True, host="127.0.0.1", port=0)
    h = serve_from_args(args, batch_dir=runs)
    try:
        assert capsys.readouterr().out == f"status page: {h.url}\n"
        assert len(get_json(h, "/api/batch")[1]["jobs"]) == 3
        assert get_json(h, "/job/1/api/status")[1]["iteration"] == 420
    finally:
        h.stop()
    assert serve_from_args(argparse.Namespace(serve=False), batch_dir=runs) is None


def test_cli_serves_a_batch(runs):
    proc = subprocess.Popen([sys.executable, "-m", "server", "--batch", str(runs), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=interruptible)
    try:
        m = re.match(r"status page: http://127\.0\.0\.1:(\d+)/", proc.stdout.readline())
        assert m
        conn = http.client.HTTPConnection("127.0.0.1", int(m.group(1)), timeout=10)
        conn.request("GET", "/job/1/api/status")
        assert json.loads(conn.getresponse().read())["iteration"] == 420
        conn.close()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0


# ------------------------------------------------------------------ in a browser (skips like test_server_browser.py)


def test_page_shows_the_batch_and_links_each_jobs_run_page(handle):
    sync_api = playwright()
    requests, errors = [], []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.on("request", lambda r: requests.append(r.url))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" and "503" not in m.text else None)
            page.goto(handle.url)
            page.wait_for_function("() => document.querySelectorAll('#batch-jobs tr.job').length === 3", timeout=15_000)
            table = page.inner_text("#batch-jobs")
            for text in ("scene-a", "scene-b", "scene-c", "24.51", "31.27", "0.83", "42 %",
                         "ValueError: no thermal frames", "5f3c8e2a…"):
                assert text in table, (text, table)
            assert [page.inner_text(f"#batch-{k}") for k in ("queued", "running", "done", "failed", "skipped")] \
                == ["0", "1", "1", "1", "0"]
            assert page.text_content("#state") == "running" and not page.is_visible("#iteration")

            page.click("#batch-jobs a >> text=scene-b")
            page.wait_for_url(handle.url + "job/1/", timeout=10_000)
            page.wait_for_function("() => document.getElementById('iteration').textContent.startsWith('420')",
                                   timeout=15_000)
            page.wait_for_function("() => document.getElementById('rgb').naturalWidth > 0", timeout=15_000)
            assert "scene-b" in page.inner_text("#title") and page.is_visible("#back")
            assert not page.is_visible("#batch-card") and not page.is_visible("#capture")
            assert page.evaluate("document.getElementById('rgb').src").startswith(handle.url + "job/1/render/latest/")
        finally:
            browser.close()
    assert requests and all(u.startswith(handle.url) or u.startswith("data:") for u in requests), requests
    assert not any("/job/" in u and "/api/batch" in u for u in requests)
    assert not errors, errors
