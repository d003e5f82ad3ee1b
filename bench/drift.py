"""Is a drift the guard stops real? Train one run with the guard's drift check off and record,
every evaluation, how far the deformation moves the median Gaussian, then grade the end.

    python bench/drift.py --out bench/results/drift --scene family-inside --seed 103 \
        --method ed3dgs-thermal --minutes 3

Two measures per evaluation (scene extents, median over 4096 Gaussians, 5 instants): ``offset``,
the largest distance from the canonical position (what the guard tests), and ``spread``, the
largest distance from the Gaussian's own mean position over time. A spread much smaller than the
offset would be a harmless gauge shift (canonical position + a constant offset renders the same);
a spread near the offset is real motion over time. Each evaluation also records the held-out
PSNR the trainer itself sees (``held_out_psnr_*``: what the guard can compare). The end is graded like `recon eval` (per
region) on the held-out rig. Writes OUT/drift-SCENE-sSEED-METHOD.json (one thread, the
protocol of bench/table.py).

    python bench/drift.py --table bench/results/residual-sparsity/dev

instead measures the finished runs of a bench/table.py output (their latest checkpoints, progress
1): how close each run ended to the guard's limit. Writes TABLE/drift.json.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

from ablation import family_data  # noqa: E402
from recon.config import GuardConfig, make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.guard import sampled_paths  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402


@torch.no_grad()
def motion(model, progress: float, extent: float, seed: int) -> dict:
    """{offset, spread} in scene extents (module docstring), on the guard's own sample."""
    idx, at = sampled_paths(model, progress, seed)
    offset = (at - model.gaussians["means"][idx]).norm(dim=2).max(0).values
    spread = (at - at.mean(0)).norm(dim=2).max(0).values
    return {"offset": round(float(offset.median()) / extent, 4), "spread": round(float(spread.median()) / extent, 4)}


def measure_table(table: Path) -> int:
    """{scene: {method: {offset, spread}}} of a table's finished runs -> TABLE/drift.json."""
    from recon.render import load_run
    out: dict = {}
    extents: dict[str, float] = {}          # a scene's methods share its dataset: load it once
    for run in sorted(table.glob("runs/*/*/checkpoints/latest.pt")):
        run_dir = run.parents[1]
        scene_name, method = run_dir.parent.name, run_dir.name
        if scene_name not in extents:
            extents[scene_name] = Scene(load_dataset(table / "data" / scene_name)).extent()
        model, _ = load_run(run_dir)
        out.setdefault(scene_name, {})[method] = motion(model, 1.0, extents[scene_name], 0)
        print(scene_name, method, out[scene_name][method], flush=True)
    path = table / "drift.json"
    path.write_text(json.dumps({"guard_limit": GuardConfig().max_median_motion, "runs": out}, indent=1))
    print(f"wrote {path}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--table", type=Path, help="measure the finished runs of this bench/table.py output instead")
    ap.add_argument("--scene", default="family-inside")
    ap.add_argument("--seed", type=int, default=103)
    ap.add_argument("--method", default="ed3dgs-thermal")
    ap.add_argument("--minutes", type=float, default=3.0)
    args = ap.parse_args()
    if args.table is not None:
        return measure_table(args.table)
    if args.out is None:
        ap.error("--out is needed to train a run (or --table to measure a table's runs)")
    torch.set_num_threads(1)
    data = family_data(args.out, args.scene, args.seed)
    cfg = make_config(args.method, minutes=args.minutes, log_every=10**9, checkpoint_every=10**9, threads=1)
    cfg.guard = GuardConfig(max_median_motion=math.inf)
    trainer = Trainer(cfg, Scene(load_dataset(data)), None, log=print)
    limit = GuardConfig().max_median_motion
    curve = []
    while not trainer.done():
        trainer.tick()
        if trainer.iteration % cfg.eval_every == 0:
            held = {k: v for k, v in (trainer.history[-1] if trainer.history else {}).items() if k.startswith("psnr_")}
            curve.append({"iteration": trainer.iteration, "seconds": round(trainer.elapsed, 1),
                          **motion(trainer.model, trainer.progress(), trainer.extent, trainer.iteration),
                          **{f"held_out_{k}": v for k, v in held.items()}})
            print(curve[-1], flush=True)
    graded = evaluate_model(trainer)
    result = {"scene": args.scene, "seed": args.seed, "method": args.method, "minutes": args.minutes,
              "guard_limit": limit, "iterations": trainer.iteration, "events": trainer.events,
              "first_over_limit": next((c["iteration"] for c in curve if c["offset"] > limit), None),
              "curve": curve, "test": {m: graded[m] for m in cfg.model.modalities},
              "regions": graded.get("regions", {})}
    path = args.out / f"drift-{args.scene}-s{args.seed}-{args.method}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1, default=float))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
