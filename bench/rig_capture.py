"""A full simulated `rig capture` (thermal 640x480 @ 30 Hz, phone 640x360 segments, sync-box lamp)
and what `rig info` makes of it, with the phone-offset error against the simulation's truth.

    PYTHONPATH=. python bench/rig_capture.py --duration 60 [--no-lamp]
writes bench/results/rig_capture_sim[_nolamp].json
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from rig.capture.config import CaptureConfig
from rig.capture.session_capture import Capture
from rig.info import session_info
from rig.session import open_session

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--no-lamp", action="store_true")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "session"
        Capture(CaptureConfig(duration_s=args.duration, out=out, sim_lamp=not args.no_lamp, progress=True)).run()
        s = open_session(out)
        info = session_info(s)
        truth = {t["file"]: t for t in s.summary["sim_truth"]}
        errors = {}
        for fs in s.sync["files"]:
            t = truth[Path(fs["file"]).name]
            errors[fs["file"]] = (fs["offset_s"] - (t["true_start_host_s"] - t["nominal_start_host_s"])) * 1e3
    result = {"info": info, "phone_offset_error_ms": errors,
              "max_abs_offset_error_ms": max(abs(e) for e in errors.values()) if errors else None}
    name = "rig_capture_sim_nolamp.json" if args.no_lamp else "rig_capture_sim.json"
    path = ROOT / "bench" / "results" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1))
    print(json.dumps({"max_abs_offset_error_ms": result["max_abs_offset_error_ms"],
                      "thermal": info["streams"]["thermal"], "rgb": info["streams"]["rgb"],
                      "sync_residual_ms": info["sync_residual_ms"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
