"""Where a body's depth goes wrong: each knot's error when the growing window takes its step in
(after the constant-velocity guess and the image-plane search) and at the end of training, and
the training views' loss as the body slides along the ray.

    python bench/track_depth.py --scene family-inside --seed 1 --iterations 2000 \
        --out bench/results/track-depth/family-inside-s1.json

Trains `dtg` with the bodies told by the simulator (bench/oracle.py's ``oracle-bodies``: which
initial points lie on which moving object, pivots at the objects' centres), so that every error
left is the paths'. Two threads, fixed length. Then:

- ``knots``: per time step taken in, per body, the distance of the body's pivot from where the
  simulator has the same material point, and its component along the training thermal camera's
  ray (positive: behind the object), at intake and at the end;
- ``landscape``: at `--probe` knots, the window loss (bench/oracle.py's renders of the views at that
  step, recon.train.curriculum.window_loss) with the body moved along the ray by fixed offsets and
  by the offset that would put it at its true depth.

Writes one JSON file and prints a summary. Development seeds only (it reads the simulator's answer).
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

import recon.train.initial as initial  # noqa: E402
from ablation import family_data  # noqa: E402
from oracle import Oracle, add_family_run_args, oracle_bodies  # noqa: E402
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.curriculum import BodySearch, frames_at  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from table import apply_overrides  # noqa: E402

OFFSETS_M = (-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3)


def camera_centre(camera) -> np.ndarray:
    vm = camera.viewmat.double().numpy()
    return -vm[:3, :3].T @ vm[:3, 3]


class Grader:
    """A body's pivot at a knot against the simulator's object (record: oracle_bodies' centre, ids)."""

    def __init__(self, trainer: Trainer, oracle: Oracle, record: dict):
        self.motion, self.oracle, self.record = trainer.model.motion, oracle, record
        self.knots = self.motion.translation.shape[1]
        self.cameras = {round(v.time, 4): v.camera for v in trainer.scene.train["thermal"]}

    def places(self, b: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(where body b's pivot is at knot j, where its material point truly is) in world m."""
        pivot = self.motion.pivots[b].double().numpy()
        where = pivot + self.motion.translation[b, j].detach().double().numpy()
        k, t0 = self.record["ids"][b], self.record["center"]
        start, now = self.oracle.pose(k, t0), self.oracle.pose(k, j / (self.knots - 1))
        return where, now.rotation @ start.rotation.T @ (pivot - start.position) + now.position

    def ray(self, j: int, point: np.ndarray) -> np.ndarray | None:
        camera = self.cameras.get(round(j / (self.knots - 1), 4))
        if camera is None:
            return None
        r = point - camera_centre(camera)
        return r / np.linalg.norm(r)

    def error(self, b: int, j: int) -> dict:
        where, true = self.places(b, j)
        ray = self.ray(j, true)
        d = where - true
        return {"m": round(float(np.linalg.norm(d)), 3),
                "along_ray_m": None if ray is None else round(float(d @ ray), 3),
                "up_m": round(float(d[2]), 3)}          # the simulator's world is z-up


@torch.no_grad()
def landscape(trainer: Trainer, grader: Grader, j: int) -> list[dict]:
    """Window loss at knot j's time with each body moved along its ray (OFFSETS_M and to its true depth)."""
    t = j / (grader.knots - 1)
    search = BodySearch(trainer.model, frames_at(trainer.scene, trainer.cfg.model.modalities, t), t)
    rows = []
    for b in range(grader.motion.count):
        where, true = grader.places(b, j)
        ray = grader.ray(j, where)
        if ray is None:
            continue
        to_true = float((true - where) @ ray)
        offsets = list(OFFSETS_M) + [to_true]
        moves = [torch.tensor(o * ray, dtype=torch.float32) for o in offsets]
        plans = search.plan(b, torch.tensor([j]), moves)
        if all(w == () for w, _, _ in plans):
            continue                       # the body draws in no view at this step
        losses = [search.loss(b, torch.tensor([j]), mv, plans) for mv in moves]
        rows.append({"knot": j, "body": b, "true_depth_offset_m": round(to_true, 3),
                     "loss": {f"{o:+.2f}": round(v, 6) for o, v in zip(OFFSETS_M, losses)},
                     "loss_at_true_depth": round(losses[-1], 6)})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_family_run_args(ap, seed=1, iterations=2000, data_dir=ROOT / "bench/results/track-depth")
    ap.add_argument("--probe", default="10,20", help="knots whose loss along the ray is sampled")
    args = ap.parse_args()
    torch.set_num_threads(2)
    data = family_data(Path(args.data_dir), args.scene, args.seed, frames=40)
    oracle, record = Oracle(args.scene, args.seed), {}
    initial._motion_bodies = oracle_bodies(oracle, record)
    cfg = make_config("dtg", iterations=args.iterations, log_every=10**9, checkpoint_every=10**9, eval_every=10**9)
    apply_overrides(cfg, json.loads(args.override))
    cfg.stop.converge = False
    trainer = Trainer(cfg, Scene(load_dataset(data)), log=lambda _: None)
    if trainer.model.motion is None:
        raise SystemExit(f"{data}: the simulator's objects left no initial points; nothing to grade")
    grader = Grader(trainer, oracle, record)
    intake, seen = {}, None
    while trainer.iteration < args.iterations:
        trainer.step()
        bounds = trainer.window.bounds
        if bounds is not None and bounds != seen:
            seen = bounds
            for j in bounds:
                intake.setdefault(j, [grader.error(b, j) for b in range(grader.motion.count)])
    knots = [{"knot": j, "t": round(j / (grader.knots - 1), 4), "intake": intake[j],
              "end": [grader.error(b, j) for b in range(grader.motion.count)]} for j in sorted(intake)]
    regions = evaluate_model(trainer, every=2)["regions"]["thermal"]
    result = {"scene": args.scene, "seed": args.seed, "iterations": args.iterations,
              "override": json.loads(args.override), "center": record["center"],
              "objects": [oracle.objects[k].shape.__class__.__name__ for k in record["ids"]],
              "test_thermal_mae_k": {k: round(v["mae_k"], 3) for k, v in regions.items()},
              "knots": knots,
              "landscape": [row for j in (int(v) for v in args.probe.split(",")) for row in landscape(trainer, grader, j)]}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print("objects", result["objects"], "centre", result["center"], "held-out thermal MAE", result["test_thermal_mae_k"])
    for row in knots[:: max(1, len(knots) // 8)]:
        print(f"knot {row['knot']:2d}: intake " + " ".join(f"{e['m']:.2f}({e['along_ray_m'] or 0:+.2f},{e['up_m']:+.2f})" for e in row["intake"])
              + " | end " + " ".join(f"{e['m']:.2f}({e['along_ray_m'] or 0:+.2f},{e['up_m']:+.2f})" for e in row["end"]))
    for row in result["landscape"]:
        print(f"knot {row['knot']} body {row['body']}: true depth at {row['true_depth_offset_m']:+.2f} m, loss there "
              f"{row['loss_at_true_depth']:.5f}; along the ray " + " ".join(f"{k}:{v:.5f}" for k, v in row["loss"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
