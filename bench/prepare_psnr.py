"""Thermal PSNR of `recon run` (dtg) on a dataset prepared from a simulated session (recovered
poses) against the same frames with the simulator's true poses.

The ground-truth-pose twin is the prepared dataset with every `transform_matrix` replaced by the
true camera-to-world, the true pinhole intrinsics, and the same sparse points moved into the
world frame by the similarity that aligns the recovered RGB camera centres to the true ones
(so both runs start from the same cloud); images, times and splits are identical. Both are
trained with the same command; the test frames of each are rendered at that dataset's own
poses (what a user would see).

The rig calibration is `--calibration FILE` (`rig calibrate` of a simulated calibration session:
the whole capture -> calibrate -> prepare -> train chain, and the twin's true thermal poses and
intrinsics then also grade the calibration) or, without it, the simulator's true calibration
(prepare's documented fallback); the JSON records which.

    PYTHONPATH=. python bench/prepare_psnr.py --session /tmp/prepare_bench/s-target \\
        --calibration CAL.json --out bench/results/prepare_psnr.json --iterations 1500
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

from recon.data import c2w_opencv_to_opengl, load_dataset
from recon.data.ply import read_points_ply, write_points_ply
from recon.prepare import REPORT_FILE, prepare_session
from recon.prepare.poses import pose_errors
from recon.prepare.simtruth import session_truth
from rig.session import open_session

from bench.prepare_accuracy import grade, load_avg


def truth_twin(session_dir: Path, data: Path, twin: Path) -> dict:
    """Copy `data` to `twin` with true poses and intrinsics. Returns the pose errors it replaced."""
    s = open_session(session_dir)
    truth = session_truth(s)
    report = json.loads((data / REPORT_FILE).read_text())
    shutil.copytree(data, twin)
    doc = json.loads((data / "transforms.json").read_text())
    rc = truth.world.rig_config
    steps = {e["step"]: e for e in report["frame_list"]}
    for f in doc["frames"]:
        e = steps[int(Path(f["file_path"]).stem.split("_")[0])]
        if f["modality"] == "rgb":
            c2w, lens = truth.rgb_pose(s.rgb[e["rgb_record"]]), rc.rgb
        else:
            c2w, lens = truth.thermal_pose(s.thermal[e["thermal_record"]]), rc.thermal
        k = lens.scaled(f["w"], f["h"])
        f["transform_matrix"] = c2w_opencv_to_opengl(c2w).tolist()
        f.update(fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy)
        for key in ("k1", "k2", "p1", "p2"):
            f.pop(key, None)
    doc["camera_model"] = "PINHOLE"
    ds = load_dataset(data)
    rgb = [fr for fr in ds.frames if fr.modality == "rgb"]
    est = np.stack([fr.c2w_opencv() for fr in rgb])
    gt = np.stack([truth.rgb_pose(s.rgb[steps[int(Path(fr.file_path).stem.split("_")[0])]["rgb_record"]])
                   for fr in rgb])
    e = pose_errors(est, gt)
    sc, r, t = e["similarity"]
    xyz, colours = read_points_ply(data / "points3d.ply")
    write_points_ply(twin / "points3d.ply", (sc * xyz @ r.T + t), colours)
    (twin / "transforms.json").write_text(json.dumps(doc, indent=1) + "\n")
    return {"rgb_rotation_deg_mean": float(e["rotation_deg"].mean()),
            "rgb_position_mm_mean": float(e["position"].mean() * 1e3), "scale": sc}


def train(data: Path, run: Path, iterations: int, seed: int) -> dict:
    shutil.rmtree(run, ignore_errors=True)
    cmd = [sys.executable, "-m", "recon", "run", str(data), "--out", str(run), "--iterations", str(iterations),
           "--seed", str(seed)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    m = json.loads((run / "metrics.json").read_text())
    return {"seconds": round(time.perf_counter() - t0, 1), "metrics": m["metrics"], "gaussians": m["gaussians"]}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--session", type=Path, required=True, help="simulated session (rig capture, target variant)")
    p.add_argument("--out", type=Path, default=Path("bench/results/prepare_psnr.json"))
    p.add_argument("--work", type=Path, default=Path("/tmp/prepare_psnr_bench"))
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--downscale", type=int, default=2)
    p.add_argument("--iterations", type=int, default=1500)
    p.add_argument("--seeds", default="0")
    p.add_argument("--calibration", type=Path,
                   help="rig_calibration.json for prepare (default: the simulator's true calibration)")
    args = p.parse_args()
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    recovered, twin = args.work / "recovered", args.work / "truth"
    prepare_session(args.session, recovered, progress=None, frames=args.frames, downscale=args.downscale,
                    calibration=args.calibration)
    replaced = truth_twin(args.session, recovered, twin)
    report = json.loads((recovered / REPORT_FILE).read_text())
    graded = grade(args.session, recovered)
    cal_arg = f" --calibration {args.calibration}" if args.calibration else ""
    results = {"session": str(args.session), "frames": args.frames, "downscale": args.downscale,
               "iterations": args.iterations, "calibration": graded["calibration"], "scale": report["scale"],
               "sfm": report["sfm"],
               "poses_replaced": replaced, "pose_errors": {k: graded[k] for k in (
                   "rgb_rotation_deg", "rgb_position_mm", "thermal_rotation_deg", "thermal_position_mm",
                   "scale_error_pct")}, "runs": [],
               "commands": [f"python -m recon prepare SESSION RECOVERED --frames {args.frames} "
                            f"--downscale {args.downscale}{cal_arg}",
                            f"python -m recon run RECOVERED --out RUN_R --iterations {args.iterations} --seed S",
                            f"python -m recon run TRUTH --out RUN_T --iterations {args.iterations} --seed S"],
               "machine": {"cpus": os.cpu_count(), "load_avg_start": load_avg()}}
    for seed in (int(s) for s in args.seeds.split(",")):
        row = {"seed": seed}
        for name, data in (("recovered", recovered), ("truth", twin)):
            row[name] = train(data, args.work / f"run-{name}-{seed}", args.iterations, seed)
            print(seed, name, json.dumps(row[name]["metrics"]), flush=True)
        row["thermal_psnr_gap_db"] = round(row["truth"]["metrics"]["thermal"]["psnr"]
                                           - row["recovered"]["metrics"]["thermal"]["psnr"], 3)
        row["rgb_psnr_gap_db"] = round(row["truth"]["metrics"]["rgb"]["psnr"]
                                       - row["recovered"]["metrics"]["rgb"]["psnr"], 3)
        results["runs"].append(row)
        results["machine"]["load_avg_now"] = load_avg()
        gaps = [r["thermal_psnr_gap_db"] for r in results["runs"]]
        results["thermal_psnr_gap_db_mean"] = float(np.mean(gaps))     # complete after every seed
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("thermal PSNR gap (truth - recovered):", gaps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
