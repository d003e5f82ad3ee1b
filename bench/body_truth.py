"""Where the rigid bodies are, graded against the simulator: are a trained dtg's bodies on their
objects, and when they are not, where are they?

    python bench/body_truth.py --scene family-inside --seed 0 --iterations 3000 \
        --out bench/results/body-truth/family-inside-s0.json

Trains `dtg` (defaults and `--override JSON` config overrides, one thread, fixed length) on the
family scene (simulated into `--data-dir` unless there), then, at five instants over the sequence:

- ``opaque``: the body Gaussians with opacity > 0.5 (either modality), how many of them lie inside a
  moving object (its true shape and pose, 3 cm of tolerance), split by gate (open: they move with
  their body), and the median height above the floor of the open ones outside every object;
- ``bodies``: per body, its open Gaussians with opacity > 0.3: their opacity-weighted centre, its
  distance to the nearest moving object's centre, the offset along the training rig's ray to that
  object (positive: behind it), and the Gaussians' RMS spread about their centre.

Writes one JSON file; prints it. Development seeds only (it reads the simulator's answer).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

from ablation import family_data  # noqa: E402
from oracle import Oracle, add_family_run_args  # noqa: E402
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.dtg.motion import apply_motion  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from table import apply_overrides  # noqa: E402

INSTANTS = (0.0, 0.25, 0.5, 0.75, 1.0)
TOLERANCE_M = 0.03


@torch.no_grad()
def body_positions(model, rows: torch.Tensor, t: float) -> np.ndarray:
    """(R, 3) world positions at time t of the Gaussians `rows` (indices)."""
    g = model.gaussians
    means, _ = apply_motion(g["means"][rows], None, g["motion_basis"][rows],
                            model.dynamic_gate(rows), model.motion, t)
    return means.numpy()


def inside_any(oracle: Oracle, p: np.ndarray, t: float) -> np.ndarray:
    """(R,) bool: p (R, 3) lies inside some moving object at time t."""
    out = np.zeros(len(p), bool)
    for k in range(len(oracle.objects)):
        out |= oracle.contains(k, t, p, TOLERANCE_M)
    return out


def grade(trainer: Trainer, oracle: Oracle) -> dict:
    model, scene = trainer.model, trainer.scene
    g = model.gaussians
    basis = g["motion_basis"].long()
    gate = model.dynamic_gate(torch.arange(len(basis))).detach()
    opacity = torch.maximum(torch.sigmoid(g["opacity_rgb"]), torch.sigmoid(g["opacity_thermal"])).detach()
    opaque = (basis > 0) & (opacity > 0.5)
    rows_open, rows_closed = (opaque & (gate > 0.5)).nonzero()[:, 0], (opaque & (gate <= 0.5)).nonzero()[:, 0]
    out = {"objects": [{"name": o.name, "size_m": round(float(o.size), 3)} for o in oracle.objects],
           "body_gaussians": int((basis > 0).sum()), "gaussians": len(basis), "opaque": [], "bodies": []}
    times = [min(scene.times, key=lambda x: abs(x - t0)) for t0 in INSTANTS]     # the nearest steps
    for t in times:
        p_open, p_closed = body_positions(model, rows_open, t), body_positions(model, rows_closed, t)
        in_open, in_closed = inside_any(oracle, p_open, t), inside_any(oracle, p_closed, t)
        out["opaque"].append({"t": round(t, 3), "open": len(p_open), "open_inside": int(in_open.sum()),
                              "closed": len(p_closed), "closed_inside": int(in_closed.sum()),
                              "open_outside_height_m": round(float(np.median(p_open[~in_open, 2])), 3)
                              if (~in_open).any() else None})
    for b in range(model.motion.count):
        rows = ((basis == b + 1) & (gate > 0.5) & (opacity > 0.3)).nonzero()[:, 0]
        entry = {"body": b + 1, "gaussians": int((basis == b + 1).sum()), "open_opaque": len(rows), "at": []}
        if len(rows):
            w = opacity[rows].numpy()
            for t in times:
                p = body_positions(model, rows, t)
                c = (p * w[:, None]).sum(0) / w.sum()
                spread = float(np.sqrt((((p - c) ** 2).sum(1) * w).sum() / w.sum()))
                centres = [oracle.centre(k, t) for k in range(len(oracle.objects))]
                k = int(np.argmin([np.linalg.norm(c - q) for q in centres]))
                ray = centres[k] - scene.views_at("thermal", t)[0].camera.center.numpy()
                off = c - centres[k]
                entry["at"].append({"t": round(t, 3), "object": k, "distance_m": round(float(np.linalg.norm(off)), 3),
                                    "along_ray_m": round(float(off @ ray / np.linalg.norm(ray)), 3),
                                    "spread_m": round(spread, 3)})
        out["bodies"].append(entry)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_family_run_args(ap, seed=0, iterations=3000, data_dir=ROOT / "bench/results/body-truth")
    ap.add_argument("--size", default="160x120", help="simulated (and trained) resolution WxH")
    args = ap.parse_args()
    torch.set_num_threads(1)
    width, height = (int(v) for v in args.size.split("x"))
    data = family_data(Path(args.data_dir) / args.size, args.scene, args.seed, frames=40,
                       width=width, height=height)
    cfg = make_config("dtg", iterations=args.iterations, threads=1)
    apply_overrides(cfg, json.loads(args.override))
    cfg.stop.converge = False
    trainer = Trainer(cfg, Scene(load_dataset(data)), log=lambda _: None)
    if trainer.model.motion is None:
        raise SystemExit(f"{data}: no moving bodies were found; nothing to grade")
    while trainer.iteration < args.iterations:
        trainer.step()
    regions = evaluate_model(trainer, every=2)["regions"]["thermal"]
    result = {"scene": args.scene, "seed": args.seed, "size": args.size, "iterations": args.iterations,
              "override": json.loads(args.override),
              "test_thermal_mae_k": {k: round(v["mae_k"], 3) for k, v in regions.items()},
              **grade(trainer, Oracle(args.scene, args.seed))}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
