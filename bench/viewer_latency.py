"""Viewer render round trip in headless Chromium, idle and while training, and what the viewer
costs training.

    PYTHONPATH=. python bench/viewer_latency.py --out bench/results/viewer_latency.json

A simulated scene (160x120, 8 time steps, 11000 points) trained briefly with `recon run` gives a
model of ~10k Gaussians. Round trip = the viewer page's own measurement (window.viewer.rtts): from
the fetch of /api/view/render at 320x240 until the RGB and colour-mapped temperature are drawn, while
Playwright drags the mouse over the RGB view (a move every 30 ms, an orbit, so the page always
wants a new pose; one request in flight, the newest pose next). The page runs in Debian's headless
Chromium in its own process tree, on the same 2 cores.

- idle: `recon view`'s arrangement, RenderService.from_run in this process, nothing else running.
- training: `recon run --serve`'s arrangement: a Trainer on the same scene (from its points,
  ~10k Gaussians) stepping in a thread of this process with TrainingFeed publishing and the
  LiveRenderService attached (renders done by the training thread between two steps, capped to
  --max-duty of the wall time: each reply names pace_ms, which the page waits before asking
  again). Also reported: the interval between pictures during the drag (what the eye sees).
- throughput: one trainer, alternating blocks of --block-s seconds, bare (feed and viewer attached,
  the poller SIGSTOPped) and served (the poller asking), each served block against the mean of the
  bare blocks on either side; median of the ratios. Pollers: "client", a process asking what the
  dragging page asks (a browser on another machine); "browser", the page in headless Chromium on
  these 2 cores, dragging through Playwright (its CPU, and the Playwright driver's, are reported:
  browser_cpu_cores, driver_cpu_cores).
"""
from __future__ import annotations

import argparse
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from server_latency import signal_tree  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


# ---------------------------------------------------------------------- the browser (its own process)
def drive(url: str, seconds: float, out: Path, mode: str) -> None:
    """Open the viewer and drag (mode "drag") or only keep it open ("idle") for `seconds`; write the
    page's round trips (ms) to `out`."""
    import math
    from playwright.sync_api import sync_playwright
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(url)
        page.wait_for_function("() => window.viewer.last !== null", timeout=120_000)
        page.evaluate("() => { window.viewer.rtts = []; window.viewer.frameGaps = []; }")
        box = page.locator("#rgb").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        end, i = time.monotonic() + seconds, 0
        if mode == "drag":
            page.mouse.move(cx, cy)
            page.mouse.down()
        while time.monotonic() < end:
            if mode == "drag":
                i += 1
                page.mouse.move(cx + 60 * math.sin(i / 40), cy + 20 * math.sin(i / 23))
            time.sleep(0.03)
        if mode == "drag":
            page.mouse.up()
        rtts = page.evaluate("() => window.viewer.rtts")
        gaps = page.evaluate("() => window.viewer.frameGaps")
        size = page.evaluate("() => [window.viewer.last.width, window.viewer.last.height]")
        browser.close()
    out.write_text(json.dumps({"rtts_ms": rtts, "frame_gaps_ms": gaps, "size": size}))


def poll(url: str, seconds: float) -> None:
    """What the page asks while dragging, without a browser (as a browser on another machine):
    renders at a pose turning a little each time, one in flight, waiting the reply's pace_ms."""
    import http.client
    import math
    from urllib.parse import urlsplit
    import numpy as np
    from server.viewer import unpack_render
    u = urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
    conn.request("GET", "/api/view/info")
    info = json.loads(conn.getresponse().read())
    base = np.asarray(info["cameras"][0]["c2w"], float)
    end, i = time.monotonic() + seconds, 0
    while time.monotonic() < end:
        i += 1
        a = 0.2 * math.sin(i / 15)
        turn = np.array([[math.cos(a), 0, math.sin(a), 0], [0, 1, 0, 0], [-math.sin(a), 0, math.cos(a), 0], [0, 0, 0, 1]])
        c2w = base @ turn
        conn.request("GET", "/api/view/render?c2w=" + ",".join(f"{v:.7f}" for v in c2w.ravel())
                     + "&t=0.5&size=320x240&client=poller")
        header, _ = unpack_render(conn.getresponse().read())
        time.sleep((header.get("pace_ms") or 30) / 1000)


def tree_cpu_s(pid: int) -> dict:
    """CPU seconds (user + system) of a process and its descendants, from /proc: "browser" (the
    Chromium processes) and "driver" (the rest: this script's client, Playwright's driver)."""
    from server_latency import descendants
    tick, total = os.sysconf("SC_CLK_TCK"), {"browser": 0.0, "driver": 0.0}
    for p in [pid, *descendants(pid)]:
        try:
            text = Path(f"/proc/{p}/stat").read_text()
            name = text[text.index("(") + 1:text.rindex(")")]
            fields = text.rsplit(")", 1)[1].split()
            kind = "browser" if "chrom" in name else "driver"
            total[kind] += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    return total


def run_driver(url: str, seconds: float, out: Path, mode: str = "drag") -> subprocess.Popen:
    if mode == "poll":
        return subprocess.Popen([sys.executable, __file__, "--drive", url, "--seconds", str(seconds), "--mode", "poll",
                                 "--result", str(out)], start_new_session=True)
    return subprocess.Popen([sys.executable, __file__, "--drive", url, "--seconds", str(seconds), "--result", str(out),
                             "--mode", mode], start_new_session=True)


def summary(rtts: list[float]) -> dict:
    xs = sorted(rtts)
    q = lambda f: round(xs[min(len(xs) - 1, int(f * len(xs)))], 1)  # noqa: E731
    return {"n": len(xs), "p50_ms": q(0.5), "p95_ms": q(0.95), "max_ms": round(xs[-1], 1),
            "mean_ms": round(statistics.mean(xs), 1)}


# ---------------------------------------------------------------------- set-up
def make_run(root: Path, points: int) -> tuple[Path, Path]:
    from recon.data.simulate import SimulateConfig, simulate_dataset
    data, run = root / "data", root / "run"
    if not (run / "checkpoints" / "latest.pt").exists():
        simulate_dataset(data, SimulateConfig(variant="default", frames=8, width=160, height=120, seed=3, points=points))
        subprocess.run([sys.executable, "-m", "recon", "run", str(data), "--out", str(run), "--iterations", "30"],
                       check=True, capture_output=True)
    return data, run


def make_trainer(data: Path):
    from recon.config import make_config
    from recon.data import load_dataset
    from recon.scene import Scene
    from recon.train.trainer import Trainer
    cfg = make_config("dtg", iterations=10**6, eval_every=10**9, log_every=10**9, checkpoint_every=10**9)
    return Trainer(cfg, Scene(load_dataset(data)), log=lambda _: None)


def latency(url: str, seconds: float, tmp: Path, name: str) -> dict:
    out = tmp / f"{name}.json"
    proc = run_driver(url, seconds, out)
    proc.wait(timeout=seconds + 180)
    got = json.loads(out.read_text())
    rtts = got["rtts_ms"][3:]           # the first renders warm up the allocator
    gaps = summary(got["frame_gaps_ms"][3:])
    return {**summary(rtts), "frame_interval": {"p50_ms": gaps["p50_ms"], "p95_ms": gaps["p95_ms"]}, "size": got["size"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench/results/viewer_latency.json")
    ap.add_argument("--work", help="keep the scene and run here (default: a temporary folder)")
    ap.add_argument("--points", type=int, default=11000)
    ap.add_argument("--seconds", type=float, default=25.0, help="seconds of dragging per latency condition")
    ap.add_argument("--blocks", type=int, default=11, help="alternating throughput blocks, odd")
    ap.add_argument("--block-s", type=float, default=6.0)
    ap.add_argument("--max-duty", type=float, default=None,
                    help="LiveRenderService max_duty while training (default: the one recon run uses)")
    ap.add_argument("--pollers", default="client,browser",
                    help="throughput conditions: client (requests only) and/or browser (the page in Chromium)")
    ap.add_argument("--nice", type=int, default=None, help="LiveRenderService nice (default: recon run's)")
    ap.add_argument("--drive"), ap.add_argument("--result"), ap.add_argument("--mode", default="drag")
    args = ap.parse_args()
    if args.drive:
        if args.mode == "poll":
            poll(args.drive, args.seconds)
        else:
            drive(args.drive, args.seconds, Path(args.result), args.mode)
        return 0
    if not os.access(CHROMIUM, os.X_OK):
        print(f"no Chromium at {CHROMIUM} (make system-deps)", file=sys.stderr)
        return 2
    import torch
    import server
    from recon.live.publish import LivePublisher, TrainingFeed
    from recon.view import LIVE_MAX_DUTY, LIVE_NICE, LiveRenderService, RenderService

    max_duty = LIVE_MAX_DUTY if args.max_duty is None else args.max_duty
    with tempfile.TemporaryDirectory() as tmpname:
        tmp = Path(tmpname)
        work = Path(args.work) if args.work else tmp
        data, run = make_run(work, args.points)
        result = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
                              "loadavg_start": os.getloadavg()},
                  "command": "PYTHONPATH=. python bench/viewer_latency.py " + " ".join(sys.argv[1:]),
                  "render_size": "320x240"}

        # idle: recon view
        service = RenderService.from_run(run)
        result["gaussians_idle"] = service.model.num_gaussians
        with server.serve("127.0.0.1", 0, run_dir=run, renderer=service) as handle:
            print(f"idle: {service.model.num_gaussians} Gaussians, dragging {args.seconds:g} s", flush=True)
            result["idle"] = latency(handle.url + "view", args.seconds, tmp, "idle")
            result["idle"]["server"] = handle.viewer_counts
        print("  ", result["idle"], flush=True)
        del service

        # training: recon run --serve
        trainer = make_trainer(data)
        nice = LIVE_NICE if args.nice is None else args.nice
        live = LiveRenderService(max_duty=max_duty, nice=nice)
        feed = TrainingFeed(LivePublisher(tmp / "live_run"))
        on_step = live.chain(feed.on_step)
        stop, counter = threading.Event(), {"it": 0}

        def loop():
            while not stop.is_set():
                on_step(trainer, trainer.step())
                counter["it"] += 1

        with server.serve("127.0.0.1", 0, run_dir=tmp / "live_run", renderer=live) as handle:
            thread = threading.Thread(target=loop, daemon=True)
            thread.start()
            time.sleep(2)
            print(f"training: {trainer.model.num_gaussians} Gaussians, dragging {args.seconds:g} s", flush=True)
            it0, t0 = counter["it"], time.perf_counter()
            result["training"] = latency(handle.url + "view", args.seconds, tmp, "training")
            result["training"].update(server=handle.viewer_counts, snapshots=live.snapshots, max_duty=max_duty, nice=nice,
                                      gaussians=trainer.model.num_gaussians,
                                      its_during=round((counter["it"] - it0) / (time.perf_counter() - t0), 2))
            print("  ", result["training"], flush=True)
            stop.set()
            thread.join()

            # throughput: the same trainer, alternating bare / served blocks, for each poller
            result["throughput"] = {}
            for poller in args.pollers.split(","):
                mode = "drag" if poller == "browser" else "poll"
                url = handle.url + ("view" if mode == "drag" else "")
                proc = run_driver(url, 3600, tmp / "tp.json", mode)
                time.sleep(10 if mode == "drag" else 2)
                rows = []
                try:
                    for b in range(args.blocks):
                        served = b % 2 == 1
                        signal_tree(proc.pid, signal.SIGCONT if served else signal.SIGSTOP)
                        r0, t0, n, c0 = handle.viewer_counts["rendered"], time.perf_counter(), 0, tree_cpu_s(proc.pid)
                        p0 = time.process_time()
                        while time.perf_counter() - t0 < args.block_s:
                            on_step(trainer, trainer.step())
                            n += 1
                        wall = time.perf_counter() - t0
                        rows.append({"served": served, "its": round(n / wall, 3),
                                     "renders": handle.viewer_counts["rendered"] - r0,
                                     **{f"{k}_cpu_cores": round((v - c0[k]) / wall, 3)
                                        for k, v in tree_cpu_s(proc.pid).items()},
                                     "trainer_process_cpu_share": round((time.process_time() - p0) / wall, 3),
                                     "gaussians": trainer.model.num_gaussians})
                        print(f"  {poller} block {b:2d} {'served' if served else 'bare  '}: {n / wall:6.2f} it/s, "
                              f"{rows[-1]['renders']} renders, CPU: browser {rows[-1]['browser_cpu_cores']:.2f}, "
                              f"driver {rows[-1]['driver_cpu_cores']:.2f} cores",
                              flush=True)
                finally:
                    signal_tree(proc.pid, signal.SIGCONT)
                    signal_tree(proc.pid, signal.SIGTERM)
                    proc.wait()
                ratios = [rows[i]["its"] / ((rows[i - 1]["its"] + rows[i + 1]["its"]) / 2)
                          for i in range(1, len(rows) - 1, 2)]
                served_rows = [r for r in rows if r["served"]]
                result["throughput"][poller] = {
                    "poller": {"browser": "the viewer page in headless Chromium on the same cores, dragging",
                               "client": "a client process asking what the dragging page asks (a browser elsewhere)"}[poller],
                    "blocks": rows, "block_s": args.block_s,
                    "served_over_bare_its_median": round(statistics.median(ratios), 3),
                    "served_over_bare_its_pairs": [round(r, 3) for r in ratios],
                    "bare_its_median": round(statistics.median(r["its"] for r in rows if not r["served"]), 2),
                    "served_its_median": round(statistics.median(r["its"] for r in served_rows), 2),
                    "renders_per_s": round(sum(r["renders"] for r in served_rows) / (len(served_rows) * args.block_s), 2),
                    "browser_cpu_cores_served_median": round(statistics.median(r["browser_cpu_cores"] for r in served_rows), 3),
                    "driver_cpu_cores_served_median": round(statistics.median(r["driver_cpu_cores"] for r in served_rows), 3)}
                print("  ", {k: v for k, v in result["throughput"][poller].items() if k != "blocks"}, flush=True)
        result["machine"]["loadavg_end"] = os.getloadavg()
        result["targets"] = {"idle_p95_ms": 150, "training_p95_ms": 400, "throughput_ratio_min": 0.85}
        result["met"] = {"idle": result["idle"]["p95_ms"] <= 150, "training": result["training"]["p95_ms"] <= 400,
                         **{f"throughput_{k}": v["served_over_bare_its_median"] >= 0.85
                            for k, v in result["throughput"].items()}}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("met",)}), f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
