"""The appliance as a user meets it: `recon demo` (simulated capture + live training + status page),
watched from outside through the page's own JSON endpoints.

    PYTHONPATH=. python bench/live_demo.py --out bench/results/live_demo.json [--duration 60]

Starts `python -m recon demo --duration D --out TMP --port P` and polls /api/status, /api/renders
and /api/capture every 0.25 s from this process, as the page does. Records, in seconds from the
start of the command: the first answer of the page, the first published status, the first time
both an RGB and a thermal render are listed for the newest time step, the moment the capture is
closed, and the end; plus the iteration reached at each of those and the final held-out metrics.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def get(url: str) -> dict | None:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return json.loads(r.read())
    except Exception:   # not up yet, 503 until published, or gone at the end
        return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="result JSON")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--after", type=int, default=1500)
    ap.add_argument("--port", type=int, default=8799)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="live_demo_"))
    base = f"http://127.0.0.1:{args.port}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "recon", "demo", "--out", str(work / "demo"),
                             "--duration", str(args.duration), "--after", str(args.after),
                             "--port", str(args.port)], env=env, cwd=ROOT,
                            stdout=open(work / "demo.log", "w"), stderr=subprocess.STDOUT)
    events: dict[str, dict] = {}

    def mark(name: str, status: dict | None) -> None:
        if name not in events:
            events[name] = {"s": round(time.perf_counter() - t0, 2),
                            "iteration": (status or {}).get("iteration")}
            print(f"{events[name]['s']:7.1f} s  {name}  (iteration {events[name]['iteration']})", flush=True)

    load = []
    while proc.poll() is None:
        status = get(base + "/api/status")
        if status is not None:
            mark("page answers with a status", status)
            renders = get(base + "/api/renders") or {}
            latest = renders.get("sets", {}).get("latest", {})
            if {"rgb.png", "thermal.png"} <= set(latest.get("files", [])):
                mark("first RGB and thermal renders", status)
            capture = get(base + "/api/capture") or {}
            if capture.get("state") == "closed":
                mark("capture closed", status)
            last_status = status
        load.append(os.getloadavg()[0])
        time.sleep(0.25)
    mark("demo finished", None)
    summary = json.loads((work / "demo" / "run" / "metrics.json").read_text()) if proc.returncode == 0 else {}
    result = {"command": f"recon demo --duration {args.duration:g} --after {args.after}",
              "returncode": proc.returncode, "events": events,
              "final_iteration": summary.get("iterations"), "train_seconds": summary.get("train_seconds"),
              "gaussians": summary.get("gaussians"), "metrics": summary.get("metrics"),
              "load_avg_1min": {"min": min(load, default=None), "max": max(load, default=None)},
              "log_tail": (work / "demo.log").read_text()[-3000:], "work_dir": str(work)}
    if "last_status" in locals():
        result["last_status"] = last_status
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "log_tail"}, indent=1))
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
