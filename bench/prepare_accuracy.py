"""Pose recovery of `recon prepare` on simulated-rig sessions, graded against the simulator's truth.

For each variant: `rig capture` a session of the simulated rig (sharp keyframes), `recon prepare`
it, then align the recovered RGB camera centres to the true ones by a similarity and report
rotation / position errors, the registered fraction, the metric-scale error, thermal pose errors
(through the same alignment) and pycolmap's wall time (the SfM step re-run `--repeats` times on
the same frames; median). The load average at the start and end is recorded: wall times are
only comparable on a quiet machine.

The rig calibration is `--calibration FILE` (e.g. `rig calibrate` of a simulated calibration
session: the whole chain) or, without it, the simulator's true calibration (prepare's documented
fallback); the JSON records which, with the file's errors against the truth.

    PYTHONPATH=. python bench/prepare_accuracy.py --calibration CAL.json --out bench/results/prepare_accuracy.json
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from recon.data import load_dataset
from recon.prepare import REPORT_FILE, PrepareError, prepare_session
from recon.prepare.poses import apply_similarity, pose_errors, rotation_angle_deg
from recon.prepare.simtruth import session_truth
from recon.sfm import SfmOptions, run_sfm
from rig.calibrate import load_calibration
from rig.session import open_session

from bench.prepare_calibration import errors


def capture(out: Path, duration: float, variant: str, keyframes: float, render_scale: float, seed: int) -> float:
    cmd = [sys.executable, "-m", "rig", "capture", "--duration", str(duration), "--out", str(out), "--quiet",
           "--sim-variant", variant, "--sim-keyframes", str(keyframes), "--sim-render-scale", str(render_scale),
           "--seed", str(seed)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _stats(x: np.ndarray, scale: float = 1.0, digits: int = 4) -> dict:
    return {"mean": round(float(x.mean()) * scale, digits), "median": round(float(np.median(x)) * scale, digits),
            "max": round(float(x.max()) * scale, digits)}


def grade(session_dir: Path, data_dir: Path) -> dict:
    """Errors of the prepared dataset's poses against the simulator's truth."""
    s = open_session(session_dir)
    truth = session_truth(s)
    report = json.loads((data_dir / REPORT_FILE).read_text())
    ds = load_dataset(data_dir)
    rgb = [f for f in ds.frames if f.modality == "rgb"]
    th = [f for f in ds.frames if f.modality == "thermal"]
    est = np.stack([f.c2w_opencv() for f in rgb])
    gt = np.stack([truth.rgb_pose(s.rgb[e["rgb_record"]]) for e in report["frame_list"]])
    e = pose_errors(est, gt)
    est_th = np.stack([f.c2w_opencv() for f in th])
    gt_th = np.stack([truth.thermal_pose(s.thermal[e2["thermal_record"]]) for e2 in report["frame_list"]])
    sc, r, t = e["similarity"]
    al_th = np.stack([apply_similarity(sc, r, t, c) for c in est_th])
    th_rot = np.array([rotation_angle_deg(a[:3, :3].T @ g[:3, :3]) for a, g in zip(al_th, gt_th)])
    th_pos = np.linalg.norm(al_th[:, :3, 3] - gt_th[:, :3, 3], axis=1)
    depth = report["scale"]["median_depth_m"]
    extent = float(np.linalg.norm(np.ptp(gt[:, :3, 3], axis=0)))
    rgb_truth_fx = truth.world.rig_config.rgb.scaled(rgb[0].width, rgb[0].height).fx
    return {
        "registered": report["sfm"]["registered"], "selected": report["frames"]["selected"],
        "registered_fraction": round(report["sfm"]["registered"] / report["frames"]["selected"], 4),
        "rgb_rotation_deg": _stats(e["rotation_deg"]), "rgb_position_mm": _stats(e["position"], 1e3, 3),
        "rgb_position_pct_of_scene_depth": _stats(e["position"] / depth, 100, 4),
        "rgb_position_pct_of_path_extent": _stats(e["position"] / extent, 100, 4),
        "scene_depth_m": depth, "camera_path_extent_m": round(extent, 4),
        "scale_error_pct": round((sc - 1) * 100, 3),
        "thermal_rotation_deg": _stats(th_rot), "thermal_position_mm": _stats(th_pos, 1e3, 3),
        "rgb_fx": round(rgb[0].fx, 2), "rgb_fx_truth": round(rgb_truth_fx, 2),
        "calibration": calibration_record(report["calibration"]),
        "sfm": report["sfm"], "scale": {k: v for k, v in report["scale"].items() if not k.startswith("grid")},
        "warnings": report["warnings"], "notes": report["notes"], "prepare_s": report["timings"].get("total_s"),
    }


def calibration_record(used: dict) -> dict:
    """The rig calibration prepare used (its report's `calibration`), with a file's errors against
    the simulated rig (the simulator's truth has none)."""
    if used.get("method") == "simulator":
        return used
    return {**used, "errors_vs_truth": errors(load_calibration(used["source"]))}


def sfm_wall_times(work: Path, repeats: int) -> list[float]:
    """pycolmap wall time of the SfM step re-run on the frames prepare picked (same options)."""
    names = sorted(p.name for p in (work / "images").glob("*.png"))
    mask = work / "masks"
    out = []
    for k in range(repeats):
        r = run_sfm(work / "images", names, work / f"rerun{k}", SfmOptions(mask_dir=mask if mask.is_dir() else None))
        out.append(r.stats["pycolmap_s"])
        shutil.rmtree(work / f"rerun{k}", ignore_errors=True)
    return out


def load_avg() -> list[float]:
    """The 1/5/15-minute load averages: other jobs on the 2 cores skew every wall time."""
    return [round(x, 2) for x in os.getloadavg()]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("bench/results/prepare_accuracy.json"))
    p.add_argument("--work", type=Path, default=Path("/tmp/prepare_bench"))
    p.add_argument("--variants", default="target,default,dark,occlusion")
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--frames", type=int, default=80)
    p.add_argument("--keyframes", type=float, default=30.0)
    p.add_argument("--render-scale", type=float, default=0.5)
    p.add_argument("--repeats", type=int, default=3, help="pycolmap timing repeats (first variant)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--calibration", type=Path,
                   help="rig_calibration.json for prepare (default: the simulator's true calibration)")
    args = p.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    results = {"config": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
               "machine": {"cpus": os.cpu_count(), "load_avg_start": load_avg()},
               "variants": {}}
    cal_arg = f" --calibration {args.calibration}" if args.calibration else ""
    for i, variant in enumerate(args.variants.split(",")):
        session, data = args.work / f"s-{variant}", args.work / f"d-{variant}"
        shutil.rmtree(session, ignore_errors=True)
        shutil.rmtree(data, ignore_errors=True)
        print(f"[{variant}] capturing {args.duration:.0f} s", flush=True)
        cap_s = capture(session, args.duration, variant, args.keyframes, args.render_scale, args.seed)
        entry = {"capture_s": round(cap_s, 1),
                 "commands": [f"python -m rig capture --duration {args.duration:g} --out SESSION --sim-variant {variant} "
                              f"--sim-keyframes {args.keyframes:g} --sim-render-scale {args.render_scale:g} "
                              f"--seed {args.seed}",
                              f"python -m recon prepare SESSION DATA --frames {args.frames}{cal_arg}"]}
        try:
            prepare_session(session, data, progress=lambda m: print(f"  {m}", flush=True), frames=args.frames,
                            calibration=args.calibration, keep_work=True)
            entry.update(grade(session, data))
            if i == 0 and args.repeats:
                entry["pycolmap_s_repeats"] = sfm_wall_times(data / ".work", args.repeats)
                entry["pycolmap_s_median"] = float(np.median(entry["pycolmap_s_repeats"] + [entry["sfm"]["pycolmap_s"]]))
        except PrepareError as exc:
            entry["refused"] = str(exc)
            rep = data / REPORT_FILE
            if rep.is_file():
                r = json.loads(rep.read_text())
                entry.update(sfm=r["sfm"], frames=r["frames"], warnings=r["warnings"])
        results["variants"][variant] = entry
        results["machine"]["load_avg_now"] = load_avg()
        print(json.dumps({k: v for k, v in entry.items() if k not in ("sfm", "commands")}, indent=1), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
