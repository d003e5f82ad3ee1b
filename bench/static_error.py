"""Where the static region's error comes from: the test rig's thermal error with and without the
rigid bodies' Gaussians, at four points of a run.

    python bench/static_error.py --data DATASET --iterations 3000 --out bench/results/static-error/NAME.jsonl

Trains `dtg` (defaults, 2 threads, fixed length) on DATASET; at 1/4, 1/2, 3/4 and the end it
grades every other test view per region (the code of `recon eval`) twice: as trained, and with
every body Gaussian's opacity (both modalities) set to zero. Where the second is lower on the
static region, the bodies draw over the static scene seen from the test rig. One JSON line per
checkpoint: thermal MAE (K) per region for both, and the body Gaussians' count.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402


def grade(trainer: Trainer, tag: str) -> dict:
    regions = evaluate_model(trainer, every=2)["regions"]["thermal"]
    return {f"{tag}_{k}": round(v["mae_k"], 3) for k, v in regions.items() if k in ("static", "moving")}


def without_bodies(trainer: Trainer) -> dict:
    """Grade with the body Gaussians transparent, then put their opacities back."""
    g = trainer.model.gaussians
    body = g["motion_basis"] > 0
    saved = {m: g[f"opacity_{m}"].data.clone() for m in trainer.cfg.model.modalities}
    for m in saved:
        g[f"opacity_{m}"].data[body] = -30.0
    try:
        return {**grade(trainer, "nobodies"), "body_gaussians": int(body.sum())}
    finally:
        for m, v in saved.items():
            g[f"opacity_{m}"].data.copy_(v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    cfg = make_config("dtg", iterations=args.iterations, threads=2)     # trained by step(): no eval or checkpoints
    cfg.stop.converge = False
    trainer = Trainer(cfg, Scene(load_dataset(args.data)), log=lambda _: None)
    if trainer.model.motion is None:
        raise SystemExit(f"{args.data}: no moving bodies were found; nothing to compare")
    marks = {args.iterations * k // 4 for k in range(1, 5)}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w") as f:
        while trainer.iteration < args.iterations:
            trainer.step()
            if trainer.iteration in marks:
                row = {"data": str(args.data), "iteration": trainer.iteration,
                       **grade(trainer, "all"), **without_bodies(trainer)}
                f.write(json.dumps(row) + "\n")
                f.flush()
                print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
