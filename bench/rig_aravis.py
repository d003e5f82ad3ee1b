"""Aravis's fake GigE camera (Debian aravis-tools) as the peer: share of complete frames at
30 Hz Mono16 640x480 over loopback.

    PYTHONPATH=. python bench/rig_aravis.py --duration 10 --repeat 3
writes bench/results/rig_aravis.json
"""
from __future__ import annotations

import argparse
import json
import queue
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

from rig.drivers.gige import GigECamera, discover

ROOT = Path(__file__).resolve().parents[1]


def run_once(duration_s: float) -> dict:
    cam = GigECamera.open("gige://127.0.0.1")
    try:
        f = cam.features
        f.set("Width", 640)
        f.set("Height", 480)
        f.set("PixelFormat", "Mono16")
        f.set("AcquisitionFrameRate", 30.0)
        stream = cam.start_stream()
        t0 = time.monotonic()
        frames = []
        while time.monotonic() - t0 < duration_s:
            try:
                frames.append(stream.get(timeout=0.5))
            except queue.Empty:
                continue
        wall = time.monotonic() - t0
        stats = asdict(stream.stats)
        cpu = stream.cpu_s
    finally:
        cam.close()
    complete = sum(fr.complete for fr in frames)
    ids = [fr.block_id for fr in frames]
    return {"duration_s": round(wall, 2), "frames": len(frames), "complete": complete,
            "complete_ratio": complete / max(len(frames) + stats["dropped"], 1),
            "fps": round(len(frames) / wall, 2), "first_block_id": ids[0] if ids else None,
            "wrapped": any(b < a for a, b in zip(ids, ids[1:])),
            "receiver_thread_cpu_percent": round(100 * cpu / wall, 1), "stream": stats}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    exe = shutil.which("arv-fake-gv-camera-0.8")
    if exe is None:
        print("arv-fake-gv-camera-0.8 not found: apt-get install aravis-tools", file=sys.stderr)
        return 1
    runs = []
    for _ in range(args.repeat):
        proc = subprocess.Popen([exe, "-i", "127.0.0.1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 10
            while not any(d.manufacturer == "Aravis" for d in discover(["127.0.0.1"], timeout_s=0.2)):
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("Aravis fake camera did not come up (UDP 3956 busy?)")
            runs.append(run_once(args.duration))
        finally:
            proc.kill()
            proc.wait()
        print(json.dumps({k: v for k, v in runs[-1].items() if k != "stream"}))
    result = {"runs": runs, "median_complete_ratio": statistics.median(r["complete_ratio"] for r in runs)}
    out = ROOT / "bench" / "results" / "rig_aravis.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps({"median_complete_ratio": result["median_complete_ratio"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
