"""The motion-prior ladder: each switch of recon/dtg/priors.py (and the model's motion options) on
family scenes at a fixed iteration count, graded per region, with its cost per iteration.

    python bench/ablation.py --out bench/results/ablation --scenes family-inside,family-outside \\
        --seeds 0-1 --iterations 3000 --jobs 2

Each rung is `NAME=METHOD:JSON` (config overrides, as bench/table.py --variant); the default
ladder is RUNGS below. Per (scene, seed, rung) it trains `--iterations` iterations (one thread per
job), then grades the test views with `recon.run.evaluate_model` (the code of `recon eval`, with
regions) and the *training* views' moving regions (is the fit there at all?), and measures how far
Gaussians move (displacement over time, in units of the scene extent: the background should
not). Writes ablation.json (every run) and ablation.md (median over seeds per scene and rung).
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402
sys.path.insert(0, str(ROOT / "bench"))

from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402
from recon.eval.evaluate import moving_masks  # noqa: E402
from recon.render import render_frame  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from table import apply_overrides, flatten, parse_seeds, parse_variant  # noqa: E402

PRIORS = {"priors.rigidity": 4, "priors.smoothness": 100}
RUNGS = [
    "dtg=dtg:{}",
    'dtg+geometry-bias=dtg:{"model.geometry_bias": true}',
    'dtg+old-deformation-lr=dtg:{"lr.deformation_scene": [0.008, 0.0008], "lr.time_embedding": [0.008, 0.0008], '
    '"lr.deformation_warmup": 0}',
    'dtg+thermal-grad=dtg:{"model.thermal_grad_to_rgb_deformation": true}',
    'dtg+paper-thermal-geometry=dtg:{"model.deform_geometry": ["rgb", "thermal"]}',
    'dtg+rigidity+smoothness=dtg:' + json.dumps({**PRIORS, "model.thermal_grad_to_rgb_deformation": True}),
    'dtg+sparsity=dtg:{"priors.sparsity": 1.0}',
    'dtg+anisotropy=dtg:{"priors.anisotropy": 1.0}',
    'dtg+trajectories=dtg:' + json.dumps({"model.trajectory_step": 2, **PRIORS, "priors.sparsity": 0.01}),
    'dtg+split+trajectories=dtg:' + json.dumps({"model.motion_split": True, "model.trajectory_step": 2, **PRIORS,
                                               "priors.sparsity": 0.1, "model.thermal_grad_to_rgb_deformation": True}),
    'dtg+gate=dtg:{"model.dynamic_gate": true, "priors.static": 0.1}',
]


@torch.no_grad()
def train_fit_moving(trainer: Trainer) -> dict:
    """Moving-region errors on every second *training* view: whether the fit is there at all."""
    ds, out = trainer.scene.dataset, {}
    views = {m: trainer.scene.train[m][::2] for m in trainer.cfg.model.modalities}
    moving = moving_masks(ds, [v.frame for vs in views.values() for v in vs])
    for m, vs in views.items():
        errs = []
        for v in vs:
            mask = moving[v.frame.file_path]
            if mask is None or not mask.any():
                continue
            pred = render_frame(trainer.model, m, v.time, v.camera)
            gt, valid = trainer.scene.target(v)
            if m == "rgb":
                errs.append(((pred.clamp(0, 1) - gt) ** 2)[torch.from_numpy(mask)].flatten())
            else:
                keep = torch.from_numpy(mask) & valid
                errs.append((trainer.scene.kelvin(pred[..., 0]) - trainer.scene.kelvin(gt)).abs()[keep])
        if errs:
            e = torch.cat(errs)
            out[f"train_{m}_moving"] = float(10 * torch.log10(1 / e.mean())) if m == "rgb" else float(e.mean())
    return out


@torch.no_grad()
def displacement(trainer: Trainer) -> dict:
    """Median and 90th percentile over Gaussians of the largest displacement over time, and the
    fraction moving more than 2 % of the scene extent."""
    model = trainer.model
    stage = model.motion_stage()
    if stage is None:
        return {}
    idx = torch.arange(model.num_gaussians)
    rest = model.gaussians["means"]
    far = torch.stack([(model.means_at(stage, t, 1.0, idx) - rest).norm(dim=1)
                       for t in np.linspace(0, 1, 9)]).max(0).values / trainer.extent
    return {"disp_p50": float(far.median()), "disp_p90": float(far.quantile(0.9)),
            "moving_fraction": float((far > 0.02).float().mean())}


def run_one(job: dict) -> dict:
    torch.set_num_threads(job["threads"])
    base, overrides = job["rung"][1]
    cfg = make_config(base, iterations=job["iterations"], log_every=10**9, checkpoint_every=10**9)
    apply_overrides(cfg, overrides)
    trainer = Trainer(cfg, Scene(load_dataset(job["data"])), log=lambda _: None)
    t0 = time.perf_counter()
    while not trainer.done():
        trainer.tick()
    wall = time.perf_counter() - t0
    row = {"scene": job["scene"], "seed": job["seed"], "rung": job["rung"][0], "iterations": trainer.iteration,
           "ms_per_it": 1000 * trainer.elapsed / trainer.iteration, "wall_s": round(wall, 1),
           "gaussians": trainer.model.num_gaussians, "rollbacks": sum(1 for e in trainer.events if not e.get("warning")),
           **{k: v for k, v in flatten(evaluate_model(trainer)).items() if v is not None},
           **train_fit_moving(trainer), **displacement(trainer)}
    print(json.dumps(row), flush=True)
    return row


KEYS = [("psnr_rgb", "RGB PSNR"), ("psnr_rgb_moving", "RGB moving"), ("psnr_thermal", "th PSNR"),
        ("mae_k_thermal", "th MAE K"), ("mae_k_moving", "MAE moving"), ("mae_k_moving_hot", "MAE moving-hot"),
        ("mae_k_static", "MAE static"), ("train_rgb_moving", "train RGB moving"),
        ("train_thermal_moving", "train MAE moving"), ("disp_p50", "disp p50"), ("moving_fraction", "moving frac"),
        ("ms_per_it", "ms/it")]


def family_data(out: Path, scene: str, seed: int, **simulate) -> Path:
    """OUT/data/SCENE-sSEED, simulated (SimulateConfig fields `simulate`) unless already there."""
    data = out / "data" / f"{scene}-s{seed}"
    if not (data / "transforms.json").exists():
        simulate_dataset(data, SimulateConfig(variant=scene, seed=seed, **simulate))
    return data


def median_cell(rows: list[dict], key: str) -> str:
    """The median of `key` over rows that have it, as a table cell ("–" when none do)."""
    vals = [r[key] for r in rows if r.get(key) is not None]
    return f"{statistics.median(vals):.3g}" if vals else "–"


def markdown(rows: list[dict], scenes: list[str], rungs: list[str]) -> str:
    parts = []
    for scene in scenes:
        lines = [f"**{scene}: median over seeds**", "", "| rung | " + " | ".join(h for _, h in KEYS) + " |",
                 "|---|" + "---|" * len(KEYS)]
        for rung in rungs:
            picked = [r for r in rows if r["scene"] == scene and r["rung"] == rung]
            cells = [median_cell(picked, key) for key, _ in KEYS]
            lines.append(f"| {rung} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="family-inside,family-outside")
    ap.add_argument("--seeds", default="0-1")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--rung", action="append", default=[], metavar="NAME=METHOD:JSON",
                    help="rungs to run (default: the ladder in RUNGS)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--frames", type=int, default=40)
    args = ap.parse_args()
    rungs = [parse_variant(r) for r in (args.rung or RUNGS)]
    scenes, seeds = args.scenes.split(","), parse_seeds(args.seeds)
    w, h = (int(v) for v in args.size.split("x"))
    jobs = []
    for scene in scenes:
        for seed in seeds:
            data = family_data(args.out, scene, seed, frames=args.frames, width=w, height=h)
            jobs += [{"scene": scene, "seed": seed, "data": str(data), "rung": rung, "iterations": args.iterations,
                      "threads": args.threads} for rung in rungs]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, jobs))
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    (args.out / "ablation.json").write_text(json.dumps({"settings": settings, "rungs": dict(rungs),
                                                        "runs": rows}, indent=1))
    (args.out / "ablation.md").write_text(markdown(rows, scenes, [r[0] for r in rungs]))
    print((args.out / "ablation.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
