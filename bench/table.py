"""Speed against accuracy: every method of the paper's Table 3 ladder on simulator scenes, same clock.

    python bench/table.py --out bench/results/table [--scenes default,dark,fast] [--minutes 5]

For each scene it simulates a prepared dataset (two rigs, train on rig 0, test on rig 1), trains
every method for the same wall-clock budget (training time only: evaluation pauses the clock),
evaluates all test views at regular checkpoints straight from the model (same encodings and
metric code as `recon eval`), then finishes the run as `recon run` does (renders, `recon eval`,
export). Writes, in --out:

  table.md / table.json      the paper-style table: PSNR and SSIM per modality, thermal MAE (K),
                             Gaussians, model bytes, train seconds; per scene and the mean
  curves.json                test metrics against training seconds, per scene and method
  speed_vs_accuracy.png      PSNR per modality against wall-clock seconds, one curve per method
  data/<scene>/, runs/<scene>/<method>/   the datasets and complete runs (a finished run is reused)
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.config import METHODS, make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402
from recon.run import evaluate_model, finish  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train import Trainer  # noqa: E402


def train_with_curve(cfg, scene: Scene, run_dir: Path, checkpoints: int, log) -> tuple[Trainer, list[dict]]:
    trainer = Trainer(cfg, scene, run_dir, log=log)
    curve, next_eval = [], 1.0 / checkpoints
    while not trainer.done():
        trainer.step()
        if trainer.progress() >= next_eval or trainer.done():
            metrics = evaluate_model(trainer, every=2)
            curve.append({"seconds": round(trainer.elapsed, 2), "iteration": trainer.iteration,
                          "gaussians": trainer.model.num_gaussians, **{
                              f"{k}_{m}": round(v, 4) for m, d in metrics.items() for k, v in d.items()}})
            log(f"  {cfg.method}: {trainer.elapsed:6.0f} s it {trainer.iteration:6d} " + " ".join(
                f"{m} {d['psnr']:.2f} dB" for m, d in metrics.items()))
            next_eval += 1.0 / checkpoints
    trainer.save_checkpoint(run_dir / "checkpoints" / "latest.pt")
    return trainer, curve


def table_rows(results: dict, methods: list[str]) -> list[dict]:
    """One row per method: mean over scenes of each summary value."""
    rows = []
    for method in methods:
        runs = [r[method] for r in results.values() if method in r]
        if not runs:
            continue
        row = {"method": method, "scenes": len(runs)}
        for key in ("psnr_rgb", "ssim_rgb", "psnr_thermal", "ssim_thermal", "mae_k_thermal",
                    "gaussians", "model_mb", "train_s", "iterations", "peak_rss_mb"):
            vals = [r[key] for r in runs if r.get(key) is not None]
            row[key] = float(np.mean(vals)) if vals else None
        rows.append(row)
    return rows


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


def summarise(summary: dict) -> dict:
    m = summary["metrics"]
    get = lambda mod, k: m.get(mod, {}).get(k)  # noqa: E731
    return {"psnr_rgb": get("rgb", "psnr"), "ssim_rgb": get("rgb", "ssim"),
            "psnr_thermal": get("thermal", "psnr"), "ssim_thermal": get("thermal", "ssim"),
            "mae_k_thermal": get("thermal", "mae_k"), "gaussians": summary["gaussians"],
            "roles": summary["gaussians_per_role"], "model_mb": summary["model_bytes"] / 1e6,
            "train_s": summary["train_seconds"], "iterations": summary["iterations"],
            "peak_rss_mb": summary.get("peak_rss_mb")}


def markdown(rows: list[dict], title: str) -> str:
    fmt = lambda v, d: "–" if v is None else f"{v:.{d}f}"  # noqa: E731
    lines = [f"**{title}**", "",
             "| method | RGB PSNR | RGB SSIM | thermal PSNR | thermal SSIM | thermal MAE (K) | Gaussians | MB | train s | it | peak RSS MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {fmt(r['psnr_rgb'], 2)} | {fmt(r['ssim_rgb'], 3)} | "
                     f"{fmt(r['psnr_thermal'], 2)} | {fmt(r['ssim_thermal'], 3)} | {fmt(r['mae_k_thermal'], 2)} | "
                     f"{fmt(r['gaussians'], 0)} | {fmt(r['model_mb'], 1)} | {fmt(r['train_s'], 0)} | {fmt(r['iterations'], 0)} | "
                     f"{fmt(r.get('peak_rss_mb'), 0)} |")
    return "\n".join(lines)


def plot(curves: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(curves)
    # One colour per method across every panel, and a legend per row: the RGB row has no
    # ed3dgs-thermal curve and the thermal row no ed3dgs-rgb one.
    colours = {m: f"C{i}" for i, m in enumerate(METHODS)}
    fig, axes = plt.subplots(2, len(scenes), figsize=(4.2 * len(scenes), 7), squeeze=False)
    for j, scene in enumerate(scenes):
        for i, mod in enumerate(("rgb", "thermal")):
            ax = axes[i, j]
            for method, curve in curves[scene].items():
                pts = [(c["seconds"], c[f"psnr_{mod}"]) for c in curve if f"psnr_{mod}" in c]
                if pts:
                    ax.plot(*zip(*pts), marker="o", ms=3, label=method, color=colours.get(method))
            ax.set_title(f"{scene}: {mod} (test rig)")
            ax.set_xlabel("training wall-clock (s, 2 CPU cores)")
            ax.set_ylabel("PSNR (dB)")
            ax.grid(alpha=0.3)
    for i in range(2):
        axes[i, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="default,dark,fast", help="simulator variants (comma-separated)")
    ap.add_argument("--methods", default=",".join(METHODS), help="methods (comma-separated)")
    ap.add_argument("--minutes", type=float, default=5.0, help="training budget per run (default 5)")
    ap.add_argument("--frames", type=int, default=40, help="time steps per scene (default 40)")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--checkpoints", type=int, default=8, help="evaluations per run (default 8)")
    ap.add_argument("--threads", type=int, default=0)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    try:                                # the chart comes last: fail now, not after hours of training
        import matplotlib  # noqa: F401
    except ImportError:
        raise SystemExit("bench/table.py draws speed_vs_accuracy.png with matplotlib: pip install -e '.[bench]'")
    w, h = (int(v) for v in args.size.split("x"))
    scenes, methods = args.scenes.split(","), args.methods.split(",")
    log = lambda msg: print(msg, flush=True)  # noqa: E731
    args.out.mkdir(parents=True, exist_ok=True)
    curves_path = args.out / "curves.json"
    curves = json.loads(curves_path.read_text()) if curves_path.exists() else {}
    results: dict[str, dict] = {}
    for scene_name in scenes:
        data = args.out / "data" / scene_name
        if not (data / "transforms.json").exists():
            log(f"simulating {scene_name} ({args.frames} steps, {args.size})")
            simulate_dataset(data, SimulateConfig(variant=scene_name, frames=args.frames, width=w, height=h, seed=0))
        scene = Scene(load_dataset(data))
        results[scene_name] = {}
        for method in methods:
            run_dir = args.out / "runs" / scene_name / method
            if (run_dir / "metrics.json").exists() and method in curves.get(scene_name, {}):
                summary = json.loads((run_dir / "metrics.json").read_text())
            else:
                log(f"{scene_name} / {method}: {args.minutes:g} min")
                cfg = make_config(method, minutes=args.minutes, log_every=10**9, eval_every=10**9,
                                  checkpoint_every=10**9)
                t0 = time.perf_counter()
                reset_peak_rss()
                trainer, curve = train_with_curve(cfg, scene, run_dir, args.checkpoints, log)
                summary = finish(trainer, run_dir, data)
                summary["peak_rss_mb"] = peak_rss_mb()        # training + finishing, whole process
                (run_dir / "metrics.json").write_text(json.dumps(summary, indent=2))
                curves.setdefault(scene_name, {})[method] = curve
                curves_path.write_text(json.dumps(curves, indent=1))
                log(f"  done in {time.perf_counter() - t0:.0f} s wall: " + json.dumps(summary["metrics"]))
            results[scene_name][method] = summarise(summary)
    mean_rows = table_rows(results, methods)
    parts = [markdown(mean_rows, f"Mean over scenes {', '.join(scenes)} ({args.minutes:g} min per run, "
                                 f"{args.size}, {args.frames} time steps, test = rig 1)")]
    for scene_name in scenes:
        parts.append(markdown(table_rows({scene_name: results[scene_name]}, methods), f"Scene {scene_name}"))
    (args.out / "table.md").write_text("\n\n".join(parts) + "\n")
    (args.out / "table.json").write_text(json.dumps({"settings": vars(args) | {"out": str(args.out)},
                                                     "mean": mean_rows, "per_scene": results}, indent=1))
    plot({s: curves[s] for s in scenes if s in curves}, args.out / "speed_vs_accuracy.png")
    print((args.out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
