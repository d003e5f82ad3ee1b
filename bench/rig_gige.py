"""GigE receiver figures: 640x480 Mono16 at 30 Hz from the project's fake camera (run in its own
process) over loopback, at 0 % and 1 % random GVSP packet loss; receiver CPU reported.

    PYTHONPATH=. python bench/rig_gige.py --duration 60 --loss 0 0.01
writes bench/results/rig_gige_loss<percent>.json
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import resource
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

from rig.drivers.gige import GigECamera, StreamConfig

ROOT = Path(__file__).resolve().parents[1]


def run(loss: float, duration_s: float, packet_size: int) -> dict:
    fake = subprocess.Popen([sys.executable, "-m", "tests.fakes.fake_gige", "--loss", str(loss)], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url = fake.stdout.readline().strip()
    try:
        cam = GigECamera.open(url)
        cam.features.set("PixelFormat", "Mono16")
        ru0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
        stream = cam.start_stream(StreamConfig(packet_size=packet_size))
        frames = []
        while time.monotonic() - t0 < duration_s:
            try:
                f = stream.get(timeout=0.5)
            except queue.Empty:
                continue
            frames.append((f.block_id, f.complete, f.missing_packets))
            if not f.complete:
                print(f"incomplete block {f.block_id}: {f.missing_packets} missing, leader {f.has_leader}",
                      file=sys.stderr)
        wall = time.monotonic() - t0
        ru1 = resource.getrusage(resource.RUSAGE_SELF)
        stats = asdict(stream.stats)
        receiver_cpu = stream.cpu_s
        cam.close()
    finally:
        fake.stdin.close()
        fake_stats = fake.stderr.read().strip().splitlines()[-1:]
        fake.wait()
    sent = json.loads(fake_stats[0]) if fake_stats else {}    # the fake's counters
    complete = sum(c for _, c, _ in frames)
    return {"loss": loss, "duration_s": round(wall, 2), "packet_size": packet_size,
            "frames_sent": sent.get("frames"), "frames_received": len(frames), "complete": complete,
            "complete_ratio": complete / len(frames) if frames else 0.0,
            "frames_lost": (sent.get("frames") or len(frames)) - complete,
            "receiver_thread_cpu_s": round(receiver_cpu, 2),
            "receiver_thread_cpu_percent": round(100 * receiver_cpu / wall, 1),
            "process_cpu_percent": round(100 * ((ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)) / wall, 1),
            "stream": stats, "fake": sent}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--loss", type=float, nargs="+", default=[0.0, 0.01])
    p.add_argument("--packet-size", type=int, default=1500)
    args = p.parse_args()
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    for loss in args.loss:
        r = run(loss, args.duration, args.packet_size)
        path = out / f"rig_gige_loss{loss * 100:g}.json"
        path.write_text(json.dumps(r, indent=1))
        print(json.dumps({k: v for k, v in r.items() if k not in ("stream", "fake")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
