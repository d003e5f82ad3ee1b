"""`rig calibrate` against the simulator's known rig calibration.

Two sources: (a) image pairs rendered exactly from the calibration world (rig 0 sweeping in
front of the heated checkerboard), (b) a `rig capture --sim-scene calibration` session (live
simulated rig: blended keyframes, a phone clock to sync, RGB corners interpolated to each
thermal frame's time). Errors of the extrinsic (baseline vector in cm, rotation in degrees)
and of the intrinsics.

    PYTHONPATH=. python bench/prepare_calibration.py --out bench/results/prepare_calibration.json
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from recon.prepare.poses import rotation_angle_deg
from rig.calibrate import RigCalibration, calibrate
from rig.sim import make_calibration_world
from rig.sim.calibration import write_view_pairs


def errors(cal: RigCalibration) -> dict:
    rc = make_calibration_world(0).rig_config
    est, true = cal.rgb_from_thermal, np.linalg.inv(rc.thermal_from_rgb)
    out = {"baseline_error_cm": round(float(np.linalg.norm(est[:3, 3] - true[:3, 3])) * 100, 4),
           "rotation_error_deg": round(rotation_angle_deg(est[:3, :3].T @ true[:3, :3]), 4),
           "baseline_cm": round(cal.baseline_m * 100, 4), "baseline_truth_cm": round(rc.baseline_m * 100, 4),
           "rms_px": cal.rms_px, "views": cal.views, "distortion_terms": (cal.target or {}).get("distortion_terms")}
    for name, lens, truth in (("rgb", cal.rgb, rc.rgb), ("thermal", cal.thermal, rc.thermal)):
        t = truth.scaled(lens.width, lens.height)
        out[f"{name}_intrinsics_error_px"] = {k: round(getattr(lens, k) - getattr(t, k), 3)
                                              for k in ("fx", "fy", "cx", "cy")}
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("bench/results/prepare_calibration.json"))
    p.add_argument("--work", type=Path, default=Path("/tmp/prepare_calib_bench"))
    p.add_argument("--views", type=int, default=20)
    p.add_argument("--duration", type=float, default=10.0)
    args = p.parse_args()
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    results = {"machine": "2 shared cores; lead re-runs on a quiet machine"}
    for size in ((640, 480), (320, 240)):
        folder = args.work / f"pairs{size[0]}"
        t0 = time.perf_counter()
        write_view_pairs(make_calibration_world(0), folder, np.linspace(0, 10, args.views, endpoint=False), size)
        t1 = time.perf_counter()
        cal = calibrate(folder)
        results[f"pairs_{size[0]}x{size[1]}"] = {**errors(cal), "render_s": round(t1 - t0, 1),
                                                 "calibrate_s": round(time.perf_counter() - t1, 2),
                                                 "command": f"rig calibrate PAIRS ({args.views} rendered views)"}
        print(size, json.dumps(results[f"pairs_{size[0]}x{size[1]}"]), flush=True)
    session = args.work / "calib-session"
    cmd = [sys.executable, "-m", "rig", "capture", "--sim-scene", "calibration", "--sim-keyframes", "30",
           "--sim-render-scale", "0.5", "--duration", str(args.duration), "--out", str(session), "--quiet"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    t1 = time.perf_counter()
    cal = calibrate(session)
    results["session"] = {**errors(cal), "capture_s": round(t1 - t0, 1), "calibrate_s": round(time.perf_counter() - t1, 2),
                          "commands": [" ".join(["python", *cmd[1:]]).replace(str(session), "SESSION"),
                                       "python -m rig calibrate SESSION"]}
    print("session", json.dumps(results["session"]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
