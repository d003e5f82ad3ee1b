"""Status-server latency on loopback, and what the server + a page cost training.

    PYTHONPATH=. python bench/server_latency.py --out bench/results/server_latency.json

Arrangement as on the appliance: server and trainer share one process (the server is a thread of
`recon run --serve`); the client is a separate process (as a browser is), which sends a bounded
loop of requests over one kept-alive connection, round robin over the page's endpoints, 20 ms
apart. Conditions: idle; a pure-Python CPU-bound thread in the server's process (the worst case
for the GIL); real DTG training (tiny simulated scene) publishing through TrainingFeed.
Throughput: one trainer alternating blocks without anything and with TrainingFeed + server + a
page attached: a client polling like the page (its endpoints, ~8 requests/s) and, where Debian's
Chromium and Playwright are installed, the real page in headless Chromium (its polling, image
decoding and chart drawing share the 2 cores with training, as on the appliance); see throughput().
"""
from __future__ import annotations

import argparse
import http.client
import json
import os
import platform
import signal
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
CHROMIUM = "/usr/bin/chromium"
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


def browser(url: str, duration_s: float) -> None:
    """Keep the status page open in headless Chromium for duration_s (it polls by itself)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = b.new_page()
        page.goto(url)
        page.wait_for_timeout(1000 * duration_s)
        b.close()


def run_browser(url: str, duration_s: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, __file__, "--browser", url, "--duration", str(duration_s)],
                            stdout=subprocess.DEVNULL)


def descendants(pid: int) -> list[int]:
    """pid and every process below it (Linux /proc). Playwright starts Chromium in its own process
    group, so signalling a group would miss it; the parent links still lead there."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def signal_tree(pid: int, sig: int) -> None:
    for p in descendants(pid):
        try:
            os.kill(p, sig)
        except ProcessLookupError:
            pass


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
    from recon.train.trainer import Trainer
    cfg = make_config("dtg", iterations=iterations, eval_every=10**9, log_every=10**9, checkpoint_every=10**9)
    return Trainer(cfg, scene, log=lambda _: None)


def throughput(scene, session: Path, run_dir: Path, blocks: int, block_s: float, poller: str = "client") -> dict:
    """One trainer, alternating blocks of `block_s` seconds: bare (no feed, the page's poller paused
    with SIGSTOP) and served (TrainingFeed on every step, poller polling). poller: "client" (a
    process requesting the page's endpoints) or "browser" (the page in headless Chromium). Each
    served block is compared with the mean of the bare blocks on either side, so slow drifts of
    machine load cancel. Also CPU seconds per iteration of this process (trainer + feed + server
    threads), which other machines' jobs disturb less than wall-clock rates; it does not count the
    browser's own CPU, which the wall-clock rate does."""
    import server
    from recon.live.publish import LivePublisher, TrainingFeed

    tr = make_trainer(scene, 10**6)
    for _ in range(5):
        tr.step()
    handle = server.serve("127.0.0.1", 0, run_dir=run_dir, session_dir=session)
    feed = TrainingFeed(LivePublisher(run_dir))
    if poller == "browser":
        proc = run_browser(handle.url, 3600)
        time.sleep(8)                   # Chromium up and the page loaded before the first block

        def pause(on: bool) -> None:
            signal_tree(proc.pid, signal.SIGSTOP if on else signal.SIGCONT)
    else:
        proc = run_client(handle.url, 0, 1.0 / len(PAGE_POLL), PAGE_POLL, duration_s=3600)

        def pause(on: bool) -> None:
            os.kill(proc.pid, signal.SIGSTOP if on else signal.SIGCONT)
    rows = []
    try:
        for b in range(blocks):
            served = b % 2 == 1
            pause(not served)
            t0, c0, n, r0 = time.perf_counter(), time.process_time(), 0, handle.counts["requests"]
            while time.perf_counter() - t0 < block_s:
                stats = tr.step()
                n += 1
                if served:
                    feed.on_step(tr, stats)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            requests = handle.counts["requests"] - r0      # the page really is attached (or paused)
            rows.append({"served": served, "its": n / wall, "cpu_s_per_it": cpu / n, "requests": requests,
                         "gaussians": tr.model.num_gaussians})
            print(f"  block {b:2d} {'served' if served else 'bare  '}: {n / wall:6.2f} it/s, "
                  f"{1e3 * cpu / n:6.1f} ms CPU/it, {requests} requests", flush=True)
    finally:
        pause(False)
        if poller == "browser":
            signal_tree(proc.pid, signal.SIGTERM)
        else:
            proc.terminate()
        proc.wait()
        handle.stop()
    ratios = {"its": [], "cpu": []}
    for i in range(1, len(rows) - 1, 2):
        before, served, after = rows[i - 1], rows[i], rows[i + 1]
        ratios["its"].append(served["its"] / ((before["its"] + after["its"]) / 2))
        ratios["cpu"].append(((before["cpu_s_per_it"] + after["cpu_s_per_it"]) / 2) / served["cpu_s_per_it"])
    return {"poller": poller, "blocks": rows, "block_s": block_s,
            "served_over_bare_its_median": round(statistics.median(ratios["its"]), 3),
            "served_over_bare_its_pairs": [round(r, 3) for r in ratios["its"]],
            "served_over_bare_cpu_median": round(statistics.median(ratios["cpu"]), 3),
            "served_over_bare_cpu_pairs": [round(r, 3) for r in ratios["cpu"]]}


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
    ap.add_argument("--blocks", type=int, default=21, help="alternating throughput blocks, odd (default: 21)")
    ap.add_argument("--block-s", type=float, default=6.0, help="seconds per throughput block (default: 6)")
    ap.add_argument("--session", help="a session folder for /api/capture (default: a 5 s simulated capture)")
    ap.add_argument("--pollers", default="client,browser",
                    help="what is attached during the throughput blocks: client, browser or both (default: %(default)s; "
                         "browser needs Debian's chromium and playwright, skipped without them)")
    ap.add_argument("--client", help=argparse.SUPPRESS)
    ap.add_argument("--browser", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--gap", type=float, default=0.02, help=argparse.SUPPRESS)
    ap.add_argument("--paths", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        print(json.dumps(client(args.client, args.n, args.gap, args.paths.split(","), args.duration)))
        return 0
    if args.browser:
        browser(args.browser, args.duration)
        return 0

    import server
    from recon.live.publish import LivePublisher, TrainingFeed

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

    results = {"machine": {"cpus": os.cpu_count(), "load_avg_start": os.getloadavg(), "python": platform.python_version(),
                           "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
                           "gomp_spincount": os.environ.get("GOMP_SPINCOUNT")},
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

    for poller in args.pollers.split(","):
        if poller == "browser" and not browser_available():
            print("throughput with a browser: skipped (needs /usr/bin/chromium and playwright)", flush=True)
            continue
        print(f"throughput, alternating bare / served blocks, page attached as a {poller}:", flush=True)
        tp = throughput(scene, session, tmp / f"run_tp_{poller}", args.blocks, args.block_s, poller)
        results["throughput" if poller == "client" else f"throughput_{poller}"] = tp
        print(f"throughput with feed + server + {poller}: {100 * tp['served_over_bare_its_median']:.1f} % of bare "
              f"(wall-clock it/s), {100 * tp['served_over_bare_cpu_median']:.1f} % (CPU per iteration)", flush=True)
    results["machine"]["load_avg_end"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"-> {args.out}")
    return 0


def browser_available() -> bool:
    try:
        import playwright  # noqa: F401
    except ImportError:
        return False
    return Path(CHROMIUM).exists()


if __name__ == "__main__":
    sys.exit(main())
