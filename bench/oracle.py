"""Where the moving objects' error comes from: dtg with parts of the answer given by the simulator.

    python bench/oracle.py --out bench/results/oracle --scenes family-inside --seeds 0 --iterations 2000

Rungs (each on the same dataset, one thread, `--iterations` iterations, graded like `recon eval`
per region, plus the moving objects in the *training* views):

- ``dtg``: the defaults (bodies from the initial points, motion learned by the growing window);
- ``oracle-bodies``: the simulator says which initial points lie on which moving object at one
  instant (the sampled instant holding points of most objects); the window grows from there;
- ``oracle-bodies+bodies-only``: the same, with the static scene kept out of the window's steps
  (``curriculum.bodies_only``);
- ``oracle-paths``: oracle bodies whose SE(3) knots are set to the true motion and frozen: the
  error that is left when only shapes, colours and temperatures are learned.

``--rungs`` picks some of them (default: all).

The gap between the last rung and the others is what tracking loses. The simulator's labels are
read from rig/sim/family.py's scene (moving objects' shapes and motions); only family variants
are supported.
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

import recon.train.initial as initial  # noqa: E402
from ablation import family_data, median_cell, train_fit_moving  # noqa: E402
from recon.batch.summary import flatten  # noqa: E402
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.run import evaluate_model  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from rig.sim.family import FamilyScene, case_of  # noqa: E402

RUNGS = ("dtg", "oracle-bodies", "oracle-bodies+bodies-only", "oracle-paths")
SAMPLES = 8        # recon simulate records the initial points at 8 instants (recon/data/simulate.py)


class Oracle:
    """The family scene behind a simulated dataset: which points are on which moving object when,
    and each object's pose at any time."""

    def __init__(self, variant: str, seed: int):
        self.scene = FamilyScene.build(case_of(variant), seed)
        self.objects = [o for o in self.scene.objects if o.moving]

    def pose(self, k: int, t: float):
        return self.objects[k].instance(t * self.scene.duration_s, self.scene.duration_s)

    def centre(self, k: int, t: float) -> np.ndarray:
        """(3,) the middle of moving object k at time t (its bounding sphere's centre), where its blob
        and so its tracked path is. Its pose's position is its local origin: a ball's and a box's
        middle, but a can's base (rig/sim/shapes.py Cylinder spans local z 0..height)."""
        return self.pose(k, t).bounding_sphere()[0]

    def contains(self, k: int, t: float, points: np.ndarray, tolerance: float) -> np.ndarray:
        """(P,) bool: points (P, 3) lie inside moving object k at time t, within tolerance (m)."""
        pose = self.pose(k, t)
        return self.objects[k].shape.contains((points - pose.position) @ pose.rotation, tolerance)

    def bodies(self, pts: torch.Tensor):
        """(instant t, members per object (bool (P,) each, empty objects skipped), object ids,
        ghosts (P,) bool: points of moving objects recorded at other instants)."""
        p = pts.numpy()
        member = {(k, i): self.contains(k, t, p, 0.012)
                  for k in range(len(self.objects)) for i, t in enumerate(np.linspace(0, 1, SAMPLES))}
        present = [sum(int(member[(k, i)].sum()) >= 3 for k in range(len(self.objects))) for i in range(SAMPLES)]
        best = max(range(SAMPLES), key=lambda i: (present[i], sum(int(member[(k, i)].sum()) for k in range(len(self.objects)))))
        ids = [k for k in range(len(self.objects)) if member[(k, best)].sum() >= 3]
        ghosts = np.zeros(len(p), bool)
        for (k, i), m in member.items():
            if i != best:
                ghosts |= m
        for k in ids:
            ghosts &= ~member[(k, best)]
        return best / (SAMPLES - 1), [member[(k, best)] for k in ids], ids, ghosts


def add_family_run_args(ap, seed: int, iterations: int, data_dir: Path) -> None:
    """The arguments of a bench script that trains one family scene and grades it against the simulator."""
    ap.add_argument("--scene", default="family-inside", help="a family variant")
    ap.add_argument("--seed", type=int, default=seed, help="a development seed (never 100-107: held out)")
    ap.add_argument("--iterations", type=int, default=iterations)
    ap.add_argument("--override", default="{}", help='config overrides, e.g. \'{"densify.moving_budget": 0.1}\'')
    ap.add_argument("--data-dir", default=str(data_dir), help="where the simulated scene is written (or found)")
    ap.add_argument("--out", required=True, help="the JSON file to write")


def oracle_bodies(oracle: Oracle, record: dict):
    """A replacement for recon.train.initial._motion_bodies that asks the simulator."""
    def motion_bodies(cfg, scene, pts, rgb, dynamic, log):
        t, members, ids, ghosts = oracle.bodies(pts)
        cfg.curriculum.center = t
        keep = torch.from_numpy(~ghosts)
        basis = torch.zeros(len(pts))
        for b, m in enumerate(members):
            basis[torch.from_numpy(m)] = b + 1
        pivots = torch.tensor(np.stack([oracle.pose(k, t).bounding_sphere()[0] for k in ids]), dtype=torch.float32) \
            if ids else torch.zeros(0, 3)
        record.update(center=t, ids=ids)
        return pts[keep], rgb[keep], (basis > 0)[keep], basis[keep], pivots
    return motion_bodies


@torch.no_grad()
def set_true_paths(model, oracle: Oracle, record: dict) -> None:
    """Knots of every body = the true motion of its object, relative to the instant it was built at."""
    from scipy.spatial.transform import Rotation
    motion, t0 = model.motion, record["center"]
    knots = motion.translation.shape[1]
    for b, k in enumerate(record["ids"]):
        start, pivot = oracle.pose(k, t0), motion.pivots[b].numpy()
        for j in range(knots):
            now = oracle.pose(k, j / (knots - 1))
            r = now.rotation @ start.rotation.T
            motion.rotation[b, j] = torch.tensor(Rotation.from_matrix(r).as_rotvec(), dtype=torch.float32)
            motion.translation[b, j] = torch.tensor(r @ (pivot - start.position) + now.position - pivot,
                                                    dtype=torch.float32)


def run_one(job: dict) -> dict:
    torch.set_num_threads(1)
    rung = job["rung"]
    cfg = make_config("dtg", iterations=job["iterations"], log_every=10**9, checkpoint_every=10**9)
    record: dict = {}
    if rung.startswith("oracle"):
        oracle = Oracle(job["scene"], job["seed"])
        initial._motion_bodies = oracle_bodies(oracle, record)
    if rung == "oracle-bodies+bodies-only":
        cfg.curriculum.bodies_only = True
    if rung == "oracle-paths":          # nothing to grow or search: the paths are given
        cfg.curriculum.grow_every, cfg.curriculum.search, cfg.curriculum.outside = 0, False, 0.0
    trainer = Trainer(cfg, Scene(load_dataset(job["data"])), log=lambda _: None)
    if rung == "oracle-paths":
        set_true_paths(trainer.model, oracle, record)
        trainer.model.motion.rotation.requires_grad_(False)          # Adam leaves them as they are
        trainer.model.motion.translation.requires_grad_(False)
    while not trainer.done():
        trainer.tick()
    row = {"scene": job["scene"], "seed": job["seed"], "rung": rung, "iterations": trainer.iteration,
           "ms_per_it": 1000 * trainer.elapsed / trainer.iteration,
           **{k: v for k, v in flatten(evaluate_model(trainer)).items() if v is not None},
           **train_fit_moving(trainer)}
    print(json.dumps(row), flush=True)
    return row


KEYS = [("psnr_rgb", "RGB PSNR"), ("psnr_rgb_moving", "RGB moving"), ("psnr_thermal", "thermal PSNR"),
        ("mae_k_thermal", "MAE K"), ("mae_k_moving", "MAE moving"), ("mae_k_moving_hot", "MAE moving-hot"),
        ("mae_k_static", "MAE static"), ("train_thermal_moving", "train MAE moving")]


def markdown(rows: list[dict]) -> str:
    lines = ["| rung | " + " | ".join(h for _, h in KEYS) + " |", "|---|" + "---|" * len(KEYS)]
    for rung in RUNGS:
        picked = [r for r in rows if r["rung"] == rung]
        if not picked:
            continue
        cells = [median_cell(picked, k) for k, _ in KEYS]
        lines.append(f"| {rung} | " + " | ".join(cells) + " |")
    return "Median over scenes and seeds.\n\n" + "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="family-inside")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--iterations", type=int, default=2000)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rungs", default=",".join(RUNGS), help=f"some of {', '.join(RUNGS)}")
    args = ap.parse_args()
    rungs = args.rungs.split(",")
    if not set(rungs) <= set(RUNGS):
        raise SystemExit(f"--rungs: unknown {sorted(set(rungs) - set(RUNGS))}; known: {', '.join(RUNGS)}")
    from recon.batch.jobs import parse_seeds
    jobs = []
    for scene in args.scenes.split(","):
        if case_of(scene) is None:
            raise SystemExit(f"--scenes: {scene} is not a family variant (family-inside, ...)")
        for seed in parse_seeds(args.seeds):
            data = family_data(args.out, scene, seed, frames=40)
            jobs += [{"scene": scene, "seed": seed, "data": str(data), "rung": r, "iterations": args.iterations}
                     for r in rungs]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, jobs))
    (args.out / "oracle.json").write_text(json.dumps({"settings": {k: str(v) for k, v in vars(args).items()},
                                                      "runs": rows}, indent=1))
    (args.out / "oracle.md").write_text(markdown(rows))
    print((args.out / "oracle.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
