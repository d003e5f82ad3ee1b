"""Speed against accuracy: methods of the paper's Table 3 ladder on families of scenes, same clock.

    python bench/table.py --out bench/results/family --scenes family-inside,family-outside \\
        --seeds 100-107 --methods dtg,ed3dgs-thermal,ed3dgs-rgb --minutes 5 --jobs 2
    python bench/table.py --out bench/results/table --scenes default,dark,fast --minutes 3
    python bench/table.py --out bench/results/resolution --scenes default --size 640x480 \
        --train-sizes 160x120,640x480 --methods dtg,dtg-crop --variant 'dtg-crop=dtg:{"crop": 0.5}' --minutes 15

A *scene* is a simulator variant (`recon simulate --variant`); with --seeds every variant is
simulated once per seed (for `family-*` variants each seed is a new scene: rig/sim/family.py).
Each (scene, seed, method) trains for the same wall-clock budget (training time only: evaluation
pauses the clock; --converge: `recon run`'s default instead, until held-out error converged
within the --minutes cap; --iterations N: exactly N iterations, the same numbers run to run),
evaluates all test views at regular checkpoints straight from the model (same encodings and
metric code as `recon eval`, with per-region errors: moving, hot, moving-hot, static), then
finishes the run as `recon run` does. --train-sizes adds a resolution axis: the same scene is
also simulated at each training size, every method trains at each, and every run is graded on
the --size test views (a model renders at any resolution: one trained at 160x120 is rendered at
640x480, not upsampled); methods are then named METHOD@WxH. --train-seeds repeats each run with
other training seeds (the config's `seed` plus k: every random draw of training): at a fixed
length a run repeats exactly, yet another seed moves a median over 7 scene seeds by as much as the
priors the tables judge (docs/training.md, "The training seed's spread"), so each scene seed's cell is
then the mean over its training seeds, and the table gives their spread. Writes, in --out:

  table.md / table.json      per scene and method: median and worst over seeds of PSNR per
                             modality, thermal MAE (K) whole-image and per region, RGB PSNR on
                             moving pixels, Gaussians, iterations, train seconds; with
                             --train-seeds each scene seed's mean over them, and per scene and
                             method the median over scene seeds of their spread (largest - smallest)
  curves.json                test metrics against training seconds, per scene, seed and method
  speed_vs_accuracy.png      median over seeds of PSNR / MAE against wall-clock seconds, and of
                             accuracy against the Gaussian count
  data/<scene>-s<seed>/, runs/<scene>-s<seed>/<method>[@t<k>]/   datasets and complete runs (reused)

The grid runs as a batch, through `recon batch`'s mechanism (recon/batch/ray_runner.py): one
Ray task per run, finished runs skipped when the command is run again, a failed run reported
without stopping the others, runs/batch.json for the status page (`python -m server --batch
OUT/runs`). --jobs N trains N runs at once on a local Ray runtime, each on --threads threads
(default 1 with several jobs): every method then runs under the same conditions, so equal wall
time stays a fair comparison. --address runs the grid on a Ray cluster instead (docs/batch.md).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

from recon.batch.jobs import Job, parse_seeds, read_json  # noqa: E402
from recon.batch.ray_runner import run_batch  # noqa: E402
from recon.batch.summary import COLUMNS, aggregate, flatten, markdown, summarise  # noqa: E402
from recon.config import DEFAULT_MINUTES, METHODS, make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402
from recon.run import evaluate_model, finish  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402

def apply_overrides(cfg, overrides: dict) -> None:
    """{"priors.rigidity": 4, "model.deform_geometry": ["rgb"]} -> set on the TrainConfig."""
    for key, value in overrides.items():
        obj, *path = [cfg, *key.split(".")]
        for part in path[:-1]:
            obj = getattr(obj, part)
        if not hasattr(obj, path[-1]):
            raise SystemExit(f"--variant: the config has no {key!r}")
        setattr(obj, path[-1], tuple(value) if isinstance(value, list) else value)
    cfg.model.__post_init__()


def parse_variant(text: str) -> tuple[str, tuple[str, dict]]:
    """'dtg+rigid=dtg:{"priors.rigidity": 4}' -> ('dtg+rigid', ('dtg', {...}))"""
    name, _, rest = text.partition("=")
    base, _, overrides = rest.partition(":")
    if not name or base not in METHODS:
        raise SystemExit(f"--variant {text!r}: expected NAME=METHOD:JSON with METHOD one of {', '.join(METHODS)}")
    return name, (base, json.loads(overrides or "{}"))


def train_with_curve(cfg, scene: Scene, run_dir: Path, checkpoints: int, log,
                     test_scene: Scene | None = None) -> tuple[Trainer, list[dict]]:
    """Train through Trainer.tick (schedule, divergence guard, held-out convergence), grading the
    test views (of test_scene, default scene's) every 1/checkpoints of the wall-clock budget, or
    of cfg.iterations when the run has no budget in minutes (bench/table.py --iterations)."""
    trainer = Trainer(cfg, scene, run_dir, log=log)
    by_time = cfg.minutes is not None or cfg.stop.converge
    budget = 60.0 * (cfg.minutes or DEFAULT_MINUTES) if by_time else float(cfg.iterations)
    clock = (lambda: trainer.elapsed) if by_time else (lambda: trainer.iteration)   # noqa: E731
    curve, next_eval = [], budget / checkpoints
    trainer.announce()
    while not trainer.done():
        trainer.tick()
        if clock() >= next_eval or trainer.done():
            metrics = evaluate_model(trainer, every=2, scene=test_scene)
            curve.append({"seconds": round(trainer.elapsed, 2), "iteration": trainer.iteration,
                          "gaussians": trainer.model.num_gaussians,
                          **{k: (round(v, 4) if v is not None else None) for k, v in flatten(metrics).items()}})
            log(f"  {cfg.method}: {trainer.elapsed:6.0f} s it {trainer.iteration:6d} " + " ".join(
                f"{m} {metrics[m]['psnr']:.2f} dB" for m in ("rgb", "thermal") if m in metrics))
            while next_eval <= clock():
                next_eval += budget / checkpoints
    trainer.save_checkpoint(run_dir / "checkpoints" / "latest.pt")
    return trainer, curve


def reset_peak_rss() -> None:
    """Linux: restart the process's VmHWM so the next read is this run's peak."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def peak_rss_mb() -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def data_folder(out: Path, name: str, size: str, graded_size: str) -> Path:
    """Where scene `name` simulated at `size` lives (at the graded size: its plain name)."""
    return out / "data" / (name if size == graded_size else f"{name}-{size}")


def table_work(job: Job, run_dir: Path, resume: bool) -> int:
    """One grid point as a batch job's work (recon.batch.execute): train with the evaluation
    curve, grade and finish into run_dir. Everything it needs is in job.spec; an interrupted
    run starts over (its curve is wall-clock based)."""
    spec = job.spec
    torch.set_num_threads(job.threads)
    log = lambda msg: print(f"[{spec['scene']} s{spec['seed']} {job.method}] {msg}", flush=True)  # noqa: E731
    base, overrides = spec["variants"].get(job.method, (job.method, {}))
    length = {"iterations": spec["iterations"]} if spec.get("iterations") else {"minutes": spec["minutes"]}
    cfg = make_config(base, **length, log_every=10**9, checkpoint_every=10**9, threads=job.threads)
    cfg.method = job.method
    cfg.stop.converge = spec["converge"]
    apply_overrides(cfg, overrides)
    cfg.seed += spec.get("train_seed", 0)
    scene = Scene(load_dataset(Path(job.input)))
    graded = Path(spec.get("graded_on") or job.input)
    test_scene = Scene(load_dataset(graded)) if graded != Path(job.input) else None
    t0 = time.perf_counter()
    reset_peak_rss()
    trainer, curve = train_with_curve(cfg, scene, run_dir, spec["checkpoints"], log, test_scene)
    summary = finish(trainer, run_dir, graded, test_scene)
    summary["peak_rss_mb"] = peak_rss_mb()
    (run_dir / "metrics.json").write_text(json.dumps(summary, indent=2))
    (run_dir / "curve.json").write_text(json.dumps(curve, indent=1))
    log(f"done in {time.perf_counter() - t0:.0f} s wall ({summary['stop_reason']})")
    return 0


def mean_over_train_seeds(rows: list[dict]) -> tuple[list[dict], dict]:
    """Runs [{"scene", "seed", "method", "train_seed", "row"}] -> (one entry per scene, seed and
    method whose row holds each COLUMNS value's mean over its training seeds and their guard
    events summed; per scene and method the median over scene seeds of each value's spread,
    largest - smallest, where a scene seed has more than one training seed)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["scene"], r["seed"], r["method"]), []).append(r["row"])
    out, spreads = [], {}
    for (scene, seed, method), runs in groups.items():
        row = {"events": sum(x.get("events", 0) for x in runs)}
        for key, *_ in COLUMNS:
            vals = [x[key] for x in runs if x.get(key) is not None]
            row[key] = float(np.mean(vals)) if vals else None
            if len(vals) > 1:
                spreads.setdefault(scene, {}).setdefault(method, {}).setdefault(key, []).append(max(vals) - min(vals))
        out.append({"scene": scene, "seed": seed, "method": method, "row": row})
    return out, {scene: {m: {k: float(np.median(v)) for k, v in keys.items()} for m, keys in methods.items()}
                 for scene, methods in spreads.items()}


def median_curve(curves: list[list[dict]], key: str, grid: np.ndarray) -> np.ndarray | None:
    """Median over seeds of a curve's value at the times of grid (each curve held flat after
    its run ended: a run that stopped early keeps its final result)."""
    tracks = []
    for curve in curves:
        pts = [(c["seconds"], c[key]) for c in curve if c.get(key) is not None]
        if pts:
            x, y = zip(*pts)
            tracks.append(np.interp(grid, x, y, left=np.nan))
    return np.nanmedian(np.stack(tracks), axis=0) if tracks else None


def plot(results: list[dict], scenes: list[str], methods: list[str], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {m: f"C{i % 10}" for i, m in enumerate([*METHODS, *(m for m in methods if m not in METHODS)])}
    panels = [("psnr_rgb", "RGB PSNR (dB)"), ("psnr_thermal", "thermal PSNR (dB)"),
              ("mae_k_moving", "thermal MAE, moving (K)"), ("gaussians", None)]
    fig, axes = plt.subplots(len(panels), len(scenes), figsize=(4.4 * len(scenes), 3.2 * len(panels)),
                             squeeze=False)
    for j, scene in enumerate(scenes):
        for method in methods:
            curves = [r["curve"] for r in results if r["scene"] == scene and r["method"] == method]
            if not curves:
                continue
            end = max(c[-1]["seconds"] for c in curves if c)
            grid = np.linspace(0, end, 60)
            for i, (key, label) in enumerate(panels[:3]):
                y = median_curve(curves, key, grid)
                if y is not None and np.isfinite(y).any():
                    axes[i, j].plot(grid, y, label=method, color=colours.get(method))
                    axes[i, j].set_ylabel(label)
                    axes[i, j].set_xlabel("training wall-clock (s)")
            # accuracy against model size: every checkpoint of every seed
            pts = [(c["gaussians"], c.get("psnr_thermal") or c.get("psnr_rgb")) for cv in curves for c in cv]
            pts = [p for p in pts if p[1] is not None]
            if pts:
                axes[3, j].scatter(*zip(*pts), s=6, label=method, color=colours.get(method))
                axes[3, j].set_xlabel("Gaussians")
                axes[3, j].set_ylabel("PSNR, thermal (RGB if none)")
        axes[0, j].set_title(f"{scene}: median over seeds")
        for i in range(len(panels)):
            axes[i, j].grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[3, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="default,dark,fast", help="simulator variants (comma-separated)")
    ap.add_argument("--seeds", default="0", help="scene seeds, e.g. 0-7 or 100-107 (default 0)")
    ap.add_argument("--tuned-seeds", default="0-7",
                    help="seeds defaults were tuned on; the table marks the others as never tuned on")
    ap.add_argument("--methods", default=",".join(METHODS), help="methods (comma-separated), or --variant names")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=METHOD:JSON",
                    help='a method with config overrides, e.g. \'dtg+rigid=dtg:{"priors.rigidity": 4}\' (repeatable)')
    ap.add_argument("--minutes", type=float, default=5.0, help="training budget per run (default 5)")
    ap.add_argument("--converge", action="store_true",
                    help="recon run's default: until held-out error converged, --minutes as the cap")
    ap.add_argument("--iterations", type=int,
                    help="train exactly N iterations per run instead of --minutes. A run is then the same "
                         "numbers every time (tests/test_table.py), where a wall-clock budget's iteration "
                         "count follows the host's speed: the same dtg runs twice at 3 min differed by up "
                         "to 1.3 K on a seed (docs/training.md). For a prior that adds no time per "
                         "iteration this pairs arms without that spread; equal-time claims need --minutes")
    ap.add_argument("--train-seeds", default="0",
                    help="training seeds per scene seed and method, e.g. 0-2 (default 0): each run's config "
                         "seed plus k; the table averages each scene seed's runs and reports their spread")
    ap.add_argument("--frames", type=int, default=40, help="time steps per scene (default 40)")
    ap.add_argument("--size", default="160x120", help="the test views' size, W x H (default 160x120)")
    ap.add_argument("--train-sizes", help="sizes to train at, comma-separated (default: --size); each run is "
                                          "graded at --size")
    ap.add_argument("--checkpoints", type=int, default=8, help="evaluations per run (default 8)")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once on this machine (default 1)")
    ap.add_argument("--address", help="a Ray cluster to run the grid on (default: a local Ray runtime)")
    ap.add_argument("--threads", type=int, default=None, help="threads per run (default: all; 1 with --jobs > 1)")
    args = ap.parse_args()
    if args.iterations and args.converge:
        ap.error("--iterations trains a fixed length; --converge lets held-out error choose it: pick one")
    threads = args.threads or (1 if args.jobs > 1 else os.cpu_count())
    sizes = args.train_sizes.split(",") if args.train_sizes else [args.size]
    scenes, methods, seeds = args.scenes.split(","), args.methods.split(","), parse_seeds(args.seeds)
    train_seeds = parse_seeds(args.train_seeds)
    tuned = set(parse_seeds(args.tuned_seeds))
    variants = dict(parse_variant(v) for v in args.variant)
    unknown = [m for m in methods if m not in METHODS and m not in variants]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}: use {', '.join(METHODS)} or define them with --variant")
    args.out.mkdir(parents=True, exist_ok=True)
    jobs, labels = [], {}
    for scene in scenes:
        for seed in seeds:
            name = f"{scene}-s{seed}"
            graded = data_folder(args.out, name, args.size, args.size)
            for size in dict.fromkeys([args.size, *sizes]):
                w, h = (int(v) for v in size.split("x"))
                data = data_folder(args.out, name, size, args.size)
                if not (data / "transforms.json").exists():
                    print(f"simulating {data.name} ({args.frames} steps, {size})", flush=True)
                    simulate_dataset(data, SimulateConfig(variant=scene, frames=args.frames, width=w, height=h,
                                                          seed=seed))
            for size in sizes:
                data = data_folder(args.out, name, size, args.size)
                for m in methods:
                    label = m if sizes == [args.size] else f"{m}@{size}"
                    for k in train_seeds:
                        job = Job(f"{name}/{label}" + (f"@t{k}" if k else ""), str(data), m, seed, threads,
                                  {"scene": scene, "seed": seed, "minutes": args.minutes, "converge": args.converge,
                                   "iterations": args.iterations, "train_seed": k, "checkpoints": args.checkpoints,
                                   "variants": variants, "graded_on": str(graded)})
                        labels[job.name] = label
                        jobs.append(job)
    methods = list(dict.fromkeys(labels.values()))
    # the grid runs as a batch (recon batch's mechanism: Ray tasks, finished runs skipped,
    # RUNS/batch.json for the status page); --jobs caps the local runtime's CPUs
    runs = args.out / "runs"
    rows = run_batch(jobs, runs, work=table_work, address=args.address,
                     local_cpus=args.jobs * threads, log=lambda msg: print(msg, flush=True))
    failed = [r for r in rows if r["state"] == "failed"]
    if failed:
        print("failed: " + "; ".join(f"{r['name']}: {r['error']}" for r in failed))
    results = [{"scene": j.spec["scene"], "seed": j.seed, "method": labels[j.name], "train_seed": j.spec["train_seed"],
                "summary": read_json(j.run_dir(runs) / "metrics.json"),
                "curve": json.loads((j.run_dir(runs) / "curve.json").read_text())}
               for j, r in zip(jobs, rows) if r["state"] != "failed"]
    rows = [{**r, "row": summarise(r["summary"])} for r in results]
    cells, spreads = mean_over_train_seeds(rows)
    parts, table = [], {"settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                        "per_run": [], "aggregate": {}}
    budget = (f"{args.iterations} iterations" if args.iterations else
              f"until converged, cap {args.minutes:g} min" if args.converge else f"{args.minutes:g} min")
    repeats = f"; each seed the mean of {len(train_seeds)} training seeds" if len(train_seeds) > 1 else ""
    for scene in scenes:
        for label, keep in (("never tuned on", lambda s: s not in tuned), ("tuned on", lambda s: s in tuned)):
            picked = [r for r in cells if r["scene"] == scene and keep(r["seed"])]
            if not picked:
                continue
            groups = {m: aggregate([r["row"] for r in picked if r["method"] == m]) for m in methods}
            groups = {m: g for m, g in groups.items() if g["seeds"]}
            seeds_text = ",".join(str(s) for s in sorted({r["seed"] for r in picked}))
            parts.append(markdown(groups, f"{scene}, seeds {seeds_text} ({label}): median (worst) over seeds; "
                                          f"{budget} per run, trained at {args.train_sizes or args.size}, graded at "
                                          f"{args.size}, {args.frames} time steps, test = rig 1{repeats}"))
            table["aggregate"][f"{scene} {label}"] = groups
    for scene, by_method in spreads.items():
        parts.append(f"**{scene}: spread between training seeds** (median over scene seeds of largest - smallest): "
                     + "; ".join(f"{m}: th MAE {v.get('mae_k_thermal', float('nan')):.2f} K, moving "
                                 f"{v.get('mae_k_moving', float('nan')):.2f} K, RGB {v.get('psnr_rgb', float('nan')):.2f} dB"
                                 for m, v in by_method.items()))
    if spreads:
        table["train_seed_spread"] = spreads
    table["per_run"] = [{"scene": r["scene"], "seed": r["seed"], "method": r["method"], "train_seed": r["train_seed"],
                         **r["row"]} for r in rows]
    (args.out / "table.md").write_text("\n\n".join(parts) + "\n")
    (args.out / "table.json").write_text(json.dumps(table, indent=1))
    (args.out / "curves.json").write_text(json.dumps(
        [{"scene": r["scene"], "seed": r["seed"], "method": r["method"], "train_seed": r["train_seed"],
          "curve": r["curve"]} for r in rows], indent=1))
    plot(rows, scenes, methods, args.out / "speed_vs_accuracy.png")
    print((args.out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
