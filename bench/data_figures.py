"""The measured figures of docs/data.md, each from one section of this script.

    PYTHONPATH=. python bench/data_figures.py --out bench/results/data_figures.json
    PYTHONPATH=. python bench/data_figures.py --out /tmp/f.json --only ssim,eval

Sections (run one at a time, in this order; each records the 1-minute load average before and
after it, because the machine is shared and other jobs skew every timing):

  memory    peak RSS (VmHWM of a fresh subprocess) of reading every frame of a 600-frame
            640x480 prepared dataset twice (500 RGB + 100 thermal, the set of
            tests/test_data_memory.py; 1.96 GB if all decoded), with the default 1 GiB image
            cache, a 256 MiB cache and an unbounded one (load_dataset(path, cache_bytes=...))
  sfm       texture check: recon.sfm.run_sfm (pycolmap, SIFT, exhaustive matching, incremental
            mapping, 2 threads) on the cam0 RGB frames of a 30-step 320x240 `default` set:
            registered frames, points, reprojection error, focal length against the truth, and
            camera-centre / rotation errors after a similarity alignment (recon.prepare.poses)
  eval      `recon eval` on noise-free world renders (rig.sim, no sensor noise) stored as the
            "model" renders of the test frames (cam1) of a 10-step 160x120 `default` set:
            mean metrics per modality, and evaluate_run's wall time with LPIPS
  ssim      recon.eval.ssim at 320x240 RGB: forward (no grad) and forward+backward, median of
            --reps runs after a warm-up, and the fastest run (less skewed by other load); with
            1 thread and with torch's default count (2 threads suffer most from other jobs)
  simulate  wall time of the `recon simulate` commands of docs/data.md, each in a subprocess
            (interpreter start included): 30 steps at 160x120, and at 320x240 with --jobs 2

The JSON written to --out holds {"command", "machine", "sections": {name: {...}}}. With --only,
the other sections already in an existing --out file are kept, so one section can be re-run.
Scratch data goes to --work (datasets are reused between runs when present, except the
`simulate` outputs, which are written afresh since writing them is what is timed).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rasterizer import _MINIMA, _peak_rss_mb, _timed  # noqa: E402  (bench/ is sys.path[0] when run as a script)

SECTIONS = ["memory", "sfm", "eval", "ssim", "simulate"]
CACHES = {"default_1GiB": None, "256MiB": 256 << 20, "unbounded": 1 << 62}
EPILOG = """more examples:
  PYTHONPATH=. python bench/data_figures.py --out /tmp/f.json --only memory --work /tmp/df
  PYTHONPATH=. python bench/data_figures.py --out /tmp/f.json --only ssim --reps 50

The whole script takes a few minutes on 2 cores (memory and simulate are the long sections).
Nothing here runs in parallel: timings on a shared machine are only comparable one at a time.
"""


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def _simulated(work: Path, frames: int, width: int, height: int) -> Path:
    """A `recon simulate` default set (seed 0, 2 rigs) in work, reused when already complete."""
    from recon.data.simulate import SimulateConfig, simulate_dataset
    out = work / f"sim-{frames}x{width}x{height}"
    if not (out / "transforms.json").is_file():
        shutil.rmtree(out, ignore_errors=True)
        simulate_dataset(out, SimulateConfig(frames=frames, width=width, height=height))
    return out


# ---------------------------------------------------------------- memory

def _memory_worker(dataset: str, cache_bytes: int | None) -> None:
    """Read every frame twice (as tests/test_data_memory.py does); print peak RSS as JSON."""
    from recon.data import load_dataset
    rss_before = _peak_rss_mb()
    ds = load_dataset(dataset) if cache_bytes is None else load_dataset(dataset, cache_bytes=cache_bytes)
    start, total = time.perf_counter(), 0.0
    for _ in range(2):
        for f in ds.frames:
            total += float(np.nanmean(ds.image(f)[::97, ::97]))
    print(json.dumps({"frames": len(ds), "cache_bytes_used": ds.cache_bytes_used,
                      "peak_rss_mb": round(_peak_rss_mb(), 1), "peak_rss_after_imports_mb": round(rss_before, 1),
                      "read_s": round(time.perf_counter() - start, 2)}))


def bench_memory(args) -> dict:
    from tests.test_data_memory import big_dataset
    data = args.work / "memory-600x640x480"
    if not (data / "transforms.json").is_file():
        shutil.rmtree(data, ignore_errors=True)
        data.mkdir(parents=True)
        big_dataset(data)
    out = {"dataset": "600 frames 640x480 (500 RGB + 100 thermal; tests/test_data_memory.py big_dataset)",
           "decoded_total_mb": round((500 * 480 * 640 * 3 * 4 + 100 * 480 * 640 * 4) / 1e6, 1), "caches": {}}
    for name, cache in CACHES.items():
        cmd = [sys.executable, __file__, "--worker", "memory", "--dataset", str(data)]
        if cache is not None:
            cmd += ["--cache-bytes", str(cache)]
        run = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT)
        out["caches"][name] = {"cache_bytes": cache or (1 << 30), **json.loads(run.stdout), "load_avg_1min": _load()}
        print(f"  memory {name}: {out['caches'][name]}", flush=True)
    return out


# ---------------------------------------------------------------- sfm

def bench_sfm(args) -> dict:
    from recon.data import load_dataset
    from recon.prepare.poses import pose_errors
    from recon.sfm import SfmOptions, run_sfm
    from rig.sim import make_world
    data = _simulated(args.work, 30, 320, 240)
    ds = load_dataset(data)
    rgb = [f for f in ds.frames if f.modality == "rgb" and f.camera == "cam0"]
    names = [Path(f.file_path).name for f in rgb]
    opt = SfmOptions(matching="exhaustive", num_threads=2)
    start = time.perf_counter()
    result = run_sfm(data / "rgb", names, args.work / "sfm-work", opt)
    wall = time.perf_counter() - start
    reg = [i for i, n in enumerate(names) if n in result.c2w]
    e = pose_errors(np.stack([result.c2w[names[i]] for i in reg]), np.stack([rgb[i].c2w_opencv() for i in reg]))
    true_f = make_world("default", 0).rig_config.rgb.scaled(320, 240).fx
    s = result.stats
    return {"dataset": "recon simulate --frames 30 --size 320x240 (default, seed 0); cam0 RGB frames",
            "options": {"matching": opt.matching, "num_threads": opt.num_threads, "camera_model": opt.camera_model},
            "registered": s["registered"], "frames": s["frames"], "points": s["points"],
            "mean_reprojection_error_px": s["mean_reprojection_error_px"],
            "mean_track_length": s["mean_track_length"], "run_sfm_s": round(wall, 2),
            "pycolmap_s": s["pycolmap_s"], "focal_px": round(result.cameras[names[reg[0]]].fx, 2),
            "focal_true_px": round(true_f, 2),
            "centre_error_mm": {"mean": round(float(e["position"].mean()) * 1e3, 3),
                                "max": round(float(e["position"].max()) * 1e3, 3)},
            "rotation_error_deg": {"mean": round(float(e["rotation_deg"].mean()), 4),
                                   "max": round(float(e["rotation_deg"].max()), 4)},
            "similarity_scale": round(float(e["scale"]), 5)}


# ---------------------------------------------------------------- eval

def bench_eval(args) -> dict:
    from recon.data import load_dataset
    from recon.eval import Lpips, evaluate_run, write_render
    from rig.sim import make_world
    data = _simulated(args.work, 10, 160, 120)
    ds = load_dataset(data)
    world = make_world("default", 0)
    run = args.work / "eval-run"
    shutil.rmtree(run, ignore_errors=True)
    test = [f for f in ds.frames if f.split == "test"]
    for f in test:  # the "model": the world rendered at the frame's exact pose and time, no sensor noise
        view = (f.c2w_opencv(), f.fx, f.fy, f.cx, f.cy, f.width, f.height, f.timestamp_s)
        image = world.render_rgb(*view) / 255.0 if f.modality == "rgb" else world.render_temperature(*view)
        write_render(run, f, image, ds.thermal_scale_k)
    start = time.perf_counter()
    result = evaluate_run(run, data)
    wall = time.perf_counter() - start
    return {"dataset": "recon simulate --frames 10 --size 160x120 (default, seed 0); test split = cam1",
            "renders": "rig.sim world.render_rgb / render_temperature at each test frame's pose, no noise",
            "lpips_available": Lpips.available(), "lpips": result["conventions"]["lpips"],
            "frames": len(test), "mean": result["mean"], "evaluate_run_s": round(wall, 2)}


# ---------------------------------------------------------------- ssim

def bench_ssim(args) -> dict:
    import torch

    from recon.eval import ssim
    gen = torch.Generator().manual_seed(0)
    gt = torch.rand(240, 320, 3, generator=gen)
    pred = (gt + 0.05 * torch.randn(240, 320, 3, generator=gen)).clamp(0, 1).requires_grad_(True)

    def forward(_):
        with torch.no_grad():
            ssim(pred, gt)

    def forward_backward(_):
        pred.grad = None
        ssim(pred, gt).backward()

    default_threads, out = torch.get_num_threads(), {"size": "320x240x3", "reps": args.reps, "by_threads": {}}
    for threads in sorted({1, default_threads}):
        torch.set_num_threads(threads)
        fwd, fwd_bwd = _timed(forward, args.reps), _timed(forward_backward, args.reps)
        out["by_threads"][str(threads)] = {
            "forward_ms": round(fwd, 3), "forward_backward_ms": round(fwd_bwd, 3),
            "forward_min_ms": round(_MINIMA[-2], 3), "forward_backward_min_ms": round(_MINIMA[-1], 3),
            "load_avg_1min": _load()}
    torch.set_num_threads(default_threads)
    return out


# ---------------------------------------------------------------- simulate

SIMULATE_RUNS = [("30 steps 160x120", ["--frames", "30", "--size", "160x120"]),
                 ("30 steps 320x240 --jobs 2", ["--frames", "30", "--size", "320x240", "--jobs", "2"])]


def bench_simulate(args) -> dict:
    out = {}
    for name, extra in SIMULATE_RUNS:
        target = args.work / ("simulate-" + "-".join(x.strip("-") for x in extra))
        shutil.rmtree(target, ignore_errors=True)
        cmd = [sys.executable, "-m", "recon", "simulate", str(target), *extra]
        load_before = _load()
        start = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=ROOT)
        wall = time.perf_counter() - start
        reported = run.stdout.strip().splitlines()[-1]  # "wrote ... (N frames) in X s"
        files = [p for p in target.rglob("*") if p.is_file()]
        out[name] = {"command": "recon simulate OUT " + " ".join(extra), "wall_s": round(wall, 2),
                     "reported": reported, "frames": sum(p.suffix == ".png" for p in files),
                     "dataset_mb": round(sum(p.stat().st_size for p in files) / 1e6, 2),
                     "load_avg_1min": {"before": load_before, "after": _load()}}
        print(f"  simulate {name}: {out[name]['wall_s']} s", flush=True)
    return out


BENCHES = {"memory": bench_memory, "sfm": bench_sfm, "eval": bench_eval, "ssim": bench_ssim,
           "simulate": bench_simulate}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, help="JSON file to write, e.g. bench/results/data_figures.json")
    p.add_argument("--only", default=",".join(SECTIONS),
                   help="comma list of sections to run (default: all: %(default)s)")
    p.add_argument("--work", type=Path, default=Path("/tmp/data_figures"),
                   help="scratch folder for datasets and runs (default: %(default)s)")
    p.add_argument("--reps", type=int, default=20, help="ssim: timed runs, median reported (default: %(default)s)")
    p.add_argument("--worker", choices=["memory"], help=argparse.SUPPRESS)
    p.add_argument("--dataset", help=argparse.SUPPRESS)
    p.add_argument("--cache-bytes", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        _memory_worker(args.dataset, args.cache_bytes)
        return 0
    if args.out is None:
        p.error("--out is required")
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = sorted(set(only) - set(SECTIONS))
    if unknown:
        p.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    args.work.mkdir(parents=True, exist_ok=True)
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    results.update(command="PYTHONPATH=. python bench/data_figures.py " + " ".join(sys.argv[1:] if argv is None else argv),
                   machine={"cpus": os.cpu_count(), "python": platform.python_version(),
                            "note": "2 cores shared with other engineers' jobs; see load_avg_1min per section"})
    sections = results.setdefault("sections", {})
    for name in SECTIONS:
        if name not in only:
            continue
        print(f"[{name}]", flush=True)
        load_before, start = _load(), time.perf_counter()
        record = BENCHES[name](args)
        sections[name] = {**record, "section_s": round(time.perf_counter() - start, 1),
                          "load_avg_1min": {"before": load_before, "after": _load()},
                          "measured_at": time.strftime("%Y-%m-%d %H:%M:%S")}
        print(f"  {json.dumps(record)[:400]}", flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")  # after each section: partial runs keep results
    return 0


if __name__ == "__main__":
    sys.exit(main())
