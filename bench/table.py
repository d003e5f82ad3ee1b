"""Speed against accuracy: methods of the paper's Table 3 ladder on families of scenes, same clock.

    python bench/table.py --out bench/results/family --scenes family-inside,family-outside \\
        --seeds 100-107 --methods dtg,ed3dgs-thermal,ed3dgs-rgb --minutes 5 --jobs 2
    python bench/table.py --out bench/results/table --scenes default,dark,fast --minutes 3

A *scene* is a simulator variant (`recon simulate --variant`); with --seeds every variant is
simulated once per seed (for `family-*` variants each seed is a new scene: rig/sim/family.py).
Each (scene, seed, method) trains for the same wall-clock budget (training time only: evaluation
pauses the clock; --converge: `recon run`'s default instead, until held-out error converged
within the --minutes cap), evaluates all test views at regular checkpoints straight from the
model (same encodings and metric code as `recon eval`, with per-region errors: moving, hot,
moving-hot, static), then finishes the run as `recon run` does. Writes, in --out:

  table.md / table.json      per scene and method: median and worst over seeds of PSNR per
                             modality, thermal MAE (K) whole-image and per region, RGB PSNR on
                             moving pixels, Gaussians, iterations, train seconds
  curves.json                test metrics against training seconds, per scene, seed and method
  speed_vs_accuracy.png      median over seeds of PSNR / MAE against wall-clock seconds, and of
                             accuracy against the Gaussian count
  data/<scene>-s<seed>/, runs/<scene>-s<seed>/<method>/   datasets and complete runs (reused)

--jobs N trains N runs at once, each on --threads threads (default 1 with several jobs): every
method then runs under the same conditions, so equal wall time stays a fair comparison.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.config import DEFAULT_MINUTES, METHODS, make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402
from recon.run import evaluate_model, finish  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402

# Summary columns: (key, header, digits, higher is better)
COLUMNS = [("psnr_rgb", "RGB PSNR", 2, True), ("psnr_rgb_moving", "RGB PSNR moving", 2, True),
           ("psnr_thermal", "th PSNR", 2, True), ("mae_k_thermal", "th MAE K", 2, False),
           ("mae_k_moving", "MAE moving", 2, False), ("mae_k_moving_hot", "MAE moving-hot", 2, False),
           ("mae_k_static", "MAE static", 2, False), ("p95_k_moving", "p95 moving", 1, False),
           ("gaussians", "Gaussians", 0, None), ("iterations", "it", 0, None), ("train_s", "train s", 0, None),
           ("ms_per_it", "ms/it", 1, None)]


def parse_seeds(text: str) -> list[int]:
    """'0-3,7' -> [0, 1, 2, 3, 7]"""
    out = []
    for part in filter(None, text.split(",")):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def flatten(metrics: dict) -> dict:
    """evaluate_model()/metrics.json metrics -> the flat summary keys of COLUMNS."""
    get = lambda *path: _dig(metrics, path)  # noqa: E731
    return {"psnr_rgb": get("rgb", "psnr"), "ssim_rgb": get("rgb", "ssim"),
            "psnr_thermal": get("thermal", "psnr"), "ssim_thermal": get("thermal", "ssim"),
            "mae_k_thermal": get("thermal", "mae_k"),
            "psnr_rgb_moving": get("regions", "rgb", "moving", "psnr"),
            "mae_k_moving": get("regions", "thermal", "moving", "mae_k"),
            "mae_k_moving_hot": get("regions", "thermal", "moving_hot", "mae_k"),
            "mae_k_static": get("regions", "thermal", "static", "mae_k"),
            "mae_k_hot": get("regions", "thermal", "hot", "mae_k"),
            "p95_k_moving": get("regions", "thermal", "moving", "p95_k")}


def _dig(d, path):
    for key in path:
        if not isinstance(d, dict) or d.get(key) is None:
            return None
        d = d[key]
    return d


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


def train_with_curve(cfg, scene: Scene, run_dir: Path, checkpoints: int, log) -> tuple[Trainer, list[dict]]:
    """Train through Trainer.tick (schedule, divergence guard, held-out convergence), grading the
    test views every 1/checkpoints of the wall-clock budget."""
    trainer = Trainer(cfg, scene, run_dir, log=log)
    budget_s = 60.0 * (cfg.minutes or DEFAULT_MINUTES)
    curve, next_eval = [], budget_s / checkpoints
    trainer.announce()
    while not trainer.done():
        trainer.tick()
        if trainer.elapsed >= next_eval or trainer.done():
            metrics = evaluate_model(trainer, every=2)
            curve.append({"seconds": round(trainer.elapsed, 2), "iteration": trainer.iteration,
                          "gaussians": trainer.model.num_gaussians,
                          **{k: (round(v, 4) if v is not None else None) for k, v in flatten(metrics).items()}})
            log(f"  {cfg.method}: {trainer.elapsed:6.0f} s it {trainer.iteration:6d} " + " ".join(
                f"{m} {metrics[m]['psnr']:.2f} dB" for m in ("rgb", "thermal") if m in metrics))
            while next_eval <= trainer.elapsed:
                next_eval += budget_s / checkpoints
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


def run_one(job: dict) -> dict:
    """Train, grade and finish one (scene, seed, method); returns its summary row and curve.
    Runs in a worker process: everything it needs is in `job`."""
    torch.set_num_threads(job["threads"]) if job["threads"] else None
    data, run_dir, method = Path(job["data"]), Path(job["run_dir"]), job["method"]
    log = lambda msg: print(f"[{job['scene']} s{job['seed']} {method}] {msg}", flush=True)  # noqa: E731
    done = run_dir / "metrics.json"
    if done.exists() and (run_dir / "curve.json").exists():
        summary = json.loads(done.read_text())
        return {"summary": summary, "curve": json.loads((run_dir / "curve.json").read_text()), **job}
    base, overrides = job["variants"].get(method, (method, {}))
    cfg = make_config(base, minutes=job["minutes"], log_every=10**9, checkpoint_every=10**9)
    cfg.method = method
    cfg.stop.converge = job["converge"]
    apply_overrides(cfg, overrides)
    scene = Scene(load_dataset(data))
    t0 = time.perf_counter()
    reset_peak_rss()
    trainer, curve = train_with_curve(cfg, scene, run_dir, job["checkpoints"], log)
    summary = finish(trainer, run_dir, data)
    summary["peak_rss_mb"] = peak_rss_mb()
    done.write_text(json.dumps(summary, indent=2))
    (run_dir / "curve.json").write_text(json.dumps(curve, indent=1))
    log(f"done in {time.perf_counter() - t0:.0f} s wall ({summary['stop_reason']})")
    return {"summary": summary, "curve": curve, **job}


def summarise(summary: dict) -> dict:
    return {**flatten(summary["metrics"]), "gaussians": summary["gaussians"],
            "roles": summary["gaussians_per_role"], "model_mb": summary["model_bytes"] / 1e6,
            "train_s": summary["train_seconds"], "iterations": summary["iterations"],
            "ms_per_it": 1000 * summary["train_seconds"] / max(summary["iterations"], 1),
            "peak_rss_mb": summary.get("peak_rss_mb"), "stop_reason": summary.get("stop_reason"),
            "events": len(summary.get("events", []))}


def aggregate(rows: list[dict]) -> dict:
    """Median and worst over seeds of every column (worst: lowest PSNR, highest error)."""
    out = {"seeds": len(rows), "events": sum(r.get("events", 0) for r in rows)}
    for key, _, _, higher in COLUMNS:
        vals = [r[key] for r in rows if r.get(key) is not None]
        if not vals:
            continue
        out[key] = statistics.median(vals)
        if higher is not None:
            out[f"{key}_worst"] = min(vals) if higher else max(vals)
    return out


def markdown(groups: dict[str, dict[str, dict]], title: str) -> str:
    """One table: rows method, cells 'median (worst)'."""
    def cell(agg, key, digits, higher):
        if agg.get(key) is None:
            return "–"
        text = f"{agg[key]:.{digits}f}"
        return text + (f" ({agg[key + '_worst']:.{digits}f})" if higher is not None and agg["seeds"] > 1 else "")
    lines = [f"**{title}**", "", "| method | seeds | " + " | ".join(c[1] for c in COLUMNS) + " | rollbacks |",
             "|---|---|" + "---|" * (len(COLUMNS) + 1)]
    for method, agg in groups.items():
        lines.append(f"| {method} | {agg['seeds']} | " + " | ".join(cell(agg, k, d, h) for k, _, d, h in COLUMNS)
                     + f" | {agg['events']} |")
    return "\n".join(lines)


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
    ap.add_argument("--frames", type=int, default=40, help="time steps per scene (default 40)")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--checkpoints", type=int, default=8, help="evaluations per run (default 8)")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (default 1)")
    ap.add_argument("--threads", type=int, default=None, help="threads per run (default: all; 1 with --jobs > 1)")
    args = ap.parse_args()
    try:                                # the chart comes last: fail now, not after hours of training
        import matplotlib  # noqa: F401
    except ImportError:
        raise SystemExit("bench/table.py draws speed_vs_accuracy.png with matplotlib: pip install -e '.[bench]'")
    threads = args.threads if args.threads is not None else (1 if args.jobs > 1 else 0)
    w, h = (int(v) for v in args.size.split("x"))
    scenes, methods, seeds = args.scenes.split(","), args.methods.split(","), parse_seeds(args.seeds)
    tuned = set(parse_seeds(args.tuned_seeds))
    variants = dict(parse_variant(v) for v in args.variant)
    unknown = [m for m in methods if m not in METHODS and m not in variants]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}: use {', '.join(METHODS)} or define them with --variant")
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for scene in scenes:
        for seed in seeds:
            name = f"{scene}-s{seed}"
            data = args.out / "data" / name
            if not (data / "transforms.json").exists():
                print(f"simulating {name} ({args.frames} steps, {args.size})", flush=True)
                simulate_dataset(data, SimulateConfig(variant=scene, frames=args.frames, width=w, height=h, seed=seed))
            jobs += [{"scene": scene, "seed": seed, "method": m, "data": str(data),
                      "run_dir": str(args.out / "runs" / name / m), "minutes": args.minutes,
                      "converge": args.converge, "checkpoints": args.checkpoints, "threads": threads,
                      "variants": variants}
                     for m in methods]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(run_one, jobs))
    else:
        results = [run_one(job) for job in jobs]
    rows = [{**r, "row": summarise(r["summary"])} for r in results]
    parts, table = [], {"settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                        "per_run": [], "aggregate": {}}
    budget = f"until converged, cap {args.minutes:g} min" if args.converge else f"{args.minutes:g} min"
    for scene in scenes:
        for label, keep in (("never tuned on", lambda s: s not in tuned), ("tuned on", lambda s: s in tuned)):
            picked = [r for r in rows if r["scene"] == scene and keep(r["seed"])]
            if not picked:
                continue
            groups = {m: aggregate([r["row"] for r in picked if r["method"] == m]) for m in methods}
            groups = {m: g for m, g in groups.items() if g["seeds"]}
            seeds_text = ",".join(str(s) for s in sorted({r["seed"] for r in picked}))
            parts.append(markdown(groups, f"{scene}, seeds {seeds_text} ({label}): median (worst) over seeds; "
                                          f"{budget} per run, {args.size}, {args.frames} time steps, test = rig 1"))
            table["aggregate"][f"{scene} {label}"] = groups
    table["per_run"] = [{"scene": r["scene"], "seed": r["seed"], "method": r["method"], **r["row"]} for r in rows]
    (args.out / "table.md").write_text("\n\n".join(parts) + "\n")
    (args.out / "table.json").write_text(json.dumps(table, indent=1))
    (args.out / "curves.json").write_text(json.dumps(
        [{"scene": r["scene"], "seed": r["seed"], "method": r["method"], "curve": r["curve"]} for r in rows], indent=1))
    plot(rows, scenes, methods, args.out / "speed_vs_accuracy.png")
    print((args.out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
