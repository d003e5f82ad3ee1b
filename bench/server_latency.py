"""Status-server latency on loopback, and what the server + a page cost training.

    PYTHONPATH=. python bench/server_latency.py --out bench/results/server_latency.json

Arrangement as on the appliance: server and trainer share one process (the server is a thread of
`recon run --serve`); the client is a separate process (as a browser is), which sends a bounded
loop of requests over one kept-alive connection, round robin over the page's endpoints, 20 ms
apart. Conditions: idle; a pure-Python CPU-bound thread in the server's process (the worst case
for the GIL); real DTG training (tiny simulated scene) publishing through TrainingFeed.
Throughput: training iterations/s without anything, vs with TrainingFeed + server + a client
polling like the page (once a second), alternated `--repeats` times; medians reported.
"""
from __future__ import annotations

import argparse
import http.client
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

ENDPOINTS = ["/", "/api/status", "/api/renders", "/api/metrics?max=400", "/api/gaussians?max=200",
             "/api/capture", "/api/sync", "/render/latest/rgb.png", "/render/latest/thermal.png",
             "/render/t03/thermal.png"]
PAGE_POLL = ["/api/status", "/api/renders", "/api/capture", "/api/sync", "/api/metrics?max=400",
             "/api/gaussians?max=200", "/render/latest/rgb.png", "/render/latest/thermal.png"]


# ---------------------------------------------------------------------- client (separate process)
def client(url: str, n: int, gap_s: float, paths: list[str], duration_s: float | None) -> dict:
    u = urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    times: dict[str, list[float]] = {p: [] for p in paths}
    statuses: dict[int, int] = {}
    end = time.monotonic() + duration_s if duration_s else None
    i = 0
    while (i < n) if end is None else (time.monotonic() < end):
        path = paths[i % len(paths)]
        t0 = time.perf_counter()
        conn.request("GET", path)
        r = conn.getresponse()
        r.read()
        times[path].append(time.perf_counter() - t0)
        statuses[r.status] = statuses.get(r.status, 0) + 1
        i += 1
        time.sleep(gap_s)
    conn.close()
    return {"times": times, "statuses": statuses}


def run_client(url: str, n: int, gap_s: float, paths: list[str], duration_s: float | None = None) -> subprocess.Popen:
    cmd = [sys.executable, __file__, "--client", url, "--n", str(n), "--gap", str(gap_s),
           "--paths", ",".join(paths)] + (["--duration", str(duration_s)] if duration_s else [])
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": "."})


def summarise(times: dict[str, list[float]]) -> dict:
    every = sorted(t for ts in times.values() for t in ts)
    q = lambda xs, p: xs[min(len(xs) - 1, int(round(p * (len(xs) - 1))))]
    return {"requests": len(every), "p50_ms": round(1e3 * q(every, 0.5), 2), "p95_ms": round(1e3 * q(every, 0.95), 2),
            "p99_ms": round(1e3 * q(every, 0.99), 2), "max_ms": round(1e3 * every[-1], 2),
            "p95_ms_by_path": {p: round(1e3 * q(sorted(ts), 0.95), 2) for p, ts in times.items() if ts}}


# ---------------------------------------------------------------------- fixtures
def make_scene(root: Path, size: str, frames: int):
    from recon.data import load_dataset
    from recon.data.simulate import SimulateConfig, simulate_dataset
    from recon.scene import Scene
    w, h = (int(v) for v in size.split("x"))
    simulate_dataset(root / "data", SimulateConfig(variant="default", frames=frames, width=w, height=h, seed=3))
    return Scene(load_dataset(root / "data"))


def make_trainer(scene, iterations: int):
    from recon.config import make_config
    from recon.train import Trainer
    cfg = make_config("dtg", iterations=iterations, eval_every=10**9, log_every=10**9, checkpoint_every=10**9)
    return Trainer(cfg, scene, log=lambda _: None)


def train_rate(scene, steps: int, feed_factory=None) -> float:
    """Iterations/s of `steps` training steps (after 5 warm-up steps), optionally publishing."""
    tr = make_trainer(scene, 10**6)
    feed = feed_factory() if feed_factory else None
    for _ in range(5):
        tr.step()
    t0 = time.perf_counter()
    for _ in range(steps):
        stats = tr.step()
        if feed:
            feed.on_step(tr, stats)
    return steps / (time.perf_counter() - t0)


def busy(stop: threading.Event) -> None:
    x = 0
    while not stop.is_set():
        for i in range(10_000):
            x += i * i


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench/results/server_latency.json", help="result file (default: %(default)s)")
    ap.add_argument("--requests", type=int, default=400, help="requests per latency condition (default: 400)")
    ap.add_argument("--size", default="128x96", help="simulated image size WxH (default: 128x96)")
    ap.add_argument("--steps", type=int, default=150, help="training steps per throughput run (default: 150)")
    ap.add_argument("--repeats", type=int, default=3, help="throughput runs per arm (default: 3)")
    ap.add_argument("--session", help="a session folder for /api/capture (default: a 5 s simulated capture)")
    ap.add_argument("--client", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--gap", type=float, default=0.02, help=argparse.SUPPRESS)
    ap.add_argument("--paths", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        print(json.dumps(client(args.client, args.n, args.gap, args.paths.split(","), args.duration)))
        return 0

    import server
    from recon.publish import LivePublisher, TrainingFeed

    tmp = Path(tempfile.mkdtemp(prefix="server_bench_"))
    session = Path(args.session) if args.session else tmp / "session"
    if not args.session:
        print("recording a 5 s simulated session...", flush=True)
        subprocess.run([sys.executable, "-m", "rig", "capture", "--duration", "5", "--out", str(session)],
                       check=True, capture_output=True, env={**os.environ, "PYTHONPATH": "."})
    print(f"simulating a {args.size} scene...", flush=True)
    scene = make_scene(tmp, args.size, 8)
    run_dir = tmp / "run"
    tr = make_trainer(scene, 10**6)
    feed = TrainingFeed(LivePublisher(run_dir), render_every_s=0.0, metric_every_s=0.0)
    for _ in range(20):
        feed.on_step(tr, tr.step())     # something of everything published before measuring
    feed.publish_renders(tr, all_slots=True)

    results = {"machine": {"cpus": os.cpu_count(), "load_avg_start": os.getloadavg(), "python": platform.python_version()},
               "size": args.size, "latency": {}, "throughput": {}}
    handle = server.serve("127.0.0.1", 0, run_dir=run_dir, session_dir=session)
    time.sleep(1.5)                     # the session monitor's first summary

    def measure(name: str) -> None:
        proc = run_client(handle.url, args.requests, 0.02, ENDPOINTS)
        out = json.loads(proc.communicate()[0])
        results["latency"][name] = {**summarise(out["times"]), "statuses": out["statuses"]}
        r = results["latency"][name]
        print(f"latency {name:>9}: p50 {r['p50_ms']:.1f} ms, p95 {r['p95_ms']:.1f} ms, max {r['max_ms']:.1f} ms "
              f"({r['requests']} requests, statuses {out['statuses']})", flush=True)

    measure("idle")
    stop = threading.Event()
    t = threading.Thread(target=busy, args=(stop,), daemon=True)
    t.start()
    measure("cpu_thread")
    stop.set()
    t.join()

    stop = threading.Event()
    live_feed = TrainingFeed(LivePublisher(run_dir))
    steps = {"n": 0}

    def train_loop() -> None:
        while not stop.is_set():
            live_feed.on_step(tr, tr.step())
            steps["n"] += 1
    t = threading.Thread(target=train_loop, daemon=True)
    t.start()
    measure("training")
    stop.set()
    t.join()
    results["latency"]["training"]["training_steps_during"] = steps["n"]
    handle.stop()

    # throughput: alternate the two arms so drifting machine load hits both alike
    bare, served = [], []
    for i in range(args.repeats):
        bare.append(train_rate(scene, args.steps))
        h = server.serve("127.0.0.1", 0, run_dir=tmp / f"run_tp{i}", session_dir=session)
        proc = run_client(h.url, 0, 1.0 / len(PAGE_POLL), PAGE_POLL, duration_s=3600)
        served.append(train_rate(scene, args.steps, lambda: TrainingFeed(LivePublisher(tmp / f"run_tp{i}"))))
        proc.terminate()
        proc.wait()
        h.stop()
        print(f"throughput run {i}: bare {bare[-1]:.2f} it/s, with feed + server + page poller {served[-1]:.2f} it/s", flush=True)
    results["throughput"] = {"bare_its": [round(x, 3) for x in bare], "served_its": [round(x, 3) for x in served],
                             "median_bare_its": round(statistics.median(bare), 3),
                             "median_served_its": round(statistics.median(served), 3),
                             "served_over_bare": round(statistics.median(served) / statistics.median(bare), 3),
                             "steps": args.steps}
    results["machine"]["load_avg_end"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"throughput with the page attached: {100 * results['throughput']['served_over_bare']:.1f} % of bare -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
