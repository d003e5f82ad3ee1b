"""Where the time of one training iteration goes, by component, at several sizes.

    python bench/train_step.py --out bench/results/train_step
    python bench/train_step.py --out /tmp/ts --sizes 160x120:10000 --methods dtg,dtg-mlp --steps 40
    python bench/train_step.py --out /tmp/ts --sizes 640x480:100000,640x480:100000@0.5 --methods dtg
    python bench/train_step.py --out /tmp/ts --sizes 160x120:10000 --methods dtg,dtg-nogeo \
        --variant 'dtg-nogeo=dtg:{"model.deform_geometry": []}'
    python bench/train_step.py --out /tmp/ts --from-run runs/s1 --progress 0.9
    python bench/train_step.py --out /tmp/ts --from-run runs/s640 --crop 1          # whole frames

For each (method or --variant, size W x H : N Gaussians) a simulated family scene (10 time steps) is trained
with N initial points and no densification (N stays fixed), on whole frames or with @F on random
windows of F x each side (`recon run --crop F`); after --warmup iterations, --steps
iterations are timed. Each component is timed *exclusively* (time inside a nested component is
its own): the native kernels (projection / rasterization, forward and backward), the deformation
networks' forward, the time embedding, the rigid motion bodies, SSIM's forward, the k-NN
smoothness, routing, autograd's own backward of the torch ops (the networks', SSIM's, ...: what
`loss.backward()` spends outside the native kernels), Adam, densification statistics and the
window's body search, image decoding (zero once the dataset's cache holds every training view, which
it does before timing: a run decodes each view once); "other" is the rest of the step (Python, loss arithmetic, indexing).

Those scenes are timed early in a run (routing all shared, the time window small). --from-run RUN
(repeatable) times a trained run instead, as it is at the end: its Gaussians, routing roles and
bodies, resumed from RUN/checkpoints/latest.pt on its dataset, the schedule held at --progress
(default: the run's own, at most 0.99); --sizes and --methods are then not used.
Writes train_step.json and train_step.md in --out.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from table import apply_overrides, parse_variant  # noqa: E402


class Timers:
    """Exclusive wall time per label: a wrapped call's time minus that of wrapped calls inside it."""

    def __init__(self):
        self.total = defaultdict(float)
        self.stack: list[list] = []          # [label, start, time of nested calls]
        self.originals: dict = {}

    def wrap(self, owner, name: str, label: str):
        fn = getattr(owner, name)
        self.originals[(owner, name)] = fn

        def timed(*args, **kwargs):
            self.stack.append([label, time.perf_counter(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                lab, start, nested = self.stack.pop()
                spent = time.perf_counter() - start
                self.total[lab] += spent - nested
                if self.stack:
                    self.stack[-1][2] += spent
        setattr(owner, name, timed)
        return fn

    def restore(self) -> None:
        for (owner, name), fn in self.originals.items():
            setattr(owner, name, fn)


def instrument(t: Timers) -> None:
    from recon.dtg import deformation, losses, model, routing, strategy, time_embedding
    from recon.splat import _native
    from recon.train import optim, trainer
    for name, label in (("project_forward", "projection fwd"), ("project_backward", "projection bwd"),
                        ("rasterize_forward", "rasterize fwd"), ("rasterize_backward", "rasterize bwd")):
        t.wrap(_native, name, label)
    t.wrap(deformation.DeformationNet, "forward", "deformation nets fwd")
    t.wrap(time_embedding.TimeEmbedding, "forward", "time embedding")
    t.wrap(model, "apply_motion", "motion bodies")
    t.wrap(losses, "ssim", "ssim fwd")
    t.wrap(losses.EmbeddingSmoothness, "__call__", "k-NN smoothness")
    for name in ("assignment", "kl_to_prior"):
        t.wrap(routing, name, "routing")
    t.wrap(torch.Tensor, "backward", "autograd bwd (torch ops)")
    t.wrap(optim.LeanAdam, "step", "adam")
    t.wrap(strategy.Strategy, "accumulate", "densify stats")
    t.wrap(strategy.Strategy, "step", "densify")
    t.wrap(trainer, "place_bases", "window body search")
    from recon.data.dataset import Dataset
    t.wrap(Dataset, "image", "images (decode, cached)")


def measure(method: str, variant: tuple[str, dict], width: int, height: int, n: int, crop: float, steps: int, warmup: int, threads: int,
            work: Path) -> dict:
    data = work / f"fam-{width}x{height}-{n}"
    if not (data / "transforms.json").exists():
        simulate_dataset(data, SimulateConfig(variant="family-inside", frames=10, width=width, height=height,
                                              seed=0, points=n))
    scene = Scene(load_dataset(data))
    base, overrides = variant
    cfg = make_config(base, iterations=3000, threads=threads, log_every=10**9, checkpoint_every=10**9,
                      eval_every=10**9, max_points=n)
    apply_overrides(cfg, overrides)
    cfg.densify.start = 2.0                 # never: N stays fixed
    cfg.stop.converge = False
    cfg.crop = crop
    trainer = Trainer(cfg, scene, log=lambda _: None)
    return timed_steps(trainer, method, f"{width}x{height}", crop, threads, steps, warmup)


def measure_run(run: Path, progress: float | None, steps: int, warmup: int, threads: int,
                crop: float | None = None) -> dict:
    """Time a trained run as it ended (RUN/checkpoints/latest.pt on the dataset RUN/scene.json names),
    the schedule held at `progress` (None: where the run ended, at most 0.99), on windows of `crop`
    of each side (1: whole frames; None: as the run trained)."""
    trainer, p = resume_held(run, threads, progress, crop)
    cam = trainer.scene.train["thermal"][0].camera
    row = timed_steps(trainer, f"{trainer.cfg.method} ({run.parent.name}/{run.name}, p {p:.2f})", f"{cam.width}x{cam.height}",
                      trainer.cfg.crop, threads, steps, warmup)
    return {**row, "run": str(run), "progress": p}


def resume_held(run: Path, threads: int | None = None, progress: float | None = None,
                crop: float | None = None) -> tuple[Trainer, float]:
    """RUN/checkpoints/latest.pt resumed on the dataset RUN/scene.json names, on `threads` threads
    (None: the run's own), the schedule held at `progress` (None: where the run ended, at most
    0.99), on windows of `crop` of each side (None: as the run trained). Returns the trainer and the
    progress it is held at."""
    data = Path(json.loads((run / "scene.json").read_text())["dataset"])
    if not (data / "transforms.json").exists():
        raise SystemExit(f"error: {run / 'scene.json'} names the dataset {data}, which is not there (moved?)")
    scene = Scene(load_dataset(data))
    trainer = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda _: None,
                             **({} if threads is None else {"threads": threads}))
    p = min(trainer.progress(), 0.99) if progress is None else progress
    trainer.progress_fn = lambda _: p
    if crop is not None:
        trainer.cfg.crop = crop
    return trainer, p


def warm_images(scene: Scene) -> None:
    """Decode every training view into the dataset's cache, as a run has after its first pass over
    the views: a short timing would otherwise charge the first decodes (~5 ms a 640x480 frame) to
    its steps."""
    for views in scene.train.values():
        for view in views:
            scene.target(view)


def timed_steps(trainer: Trainer, method: str, size: str, crop: float, threads: int, steps: int, warmup: int) -> dict:
    warm_images(trainer.scene)
    for _ in range(warmup):
        trainer.step()
    timers = Timers()
    instrument(timers)
    per_step = []
    try:
        for _ in range(steps):
            t0 = time.perf_counter()
            trainer.step()
            per_step.append(time.perf_counter() - t0)
    finally:
        timers.restore()
    total = sum(per_step)
    parts = {k: 1000 * v / steps for k, v in sorted(timers.total.items(), key=lambda kv: -kv[1])}
    parts["other (python, loss arithmetic, indexing)"] = 1000 * total / steps - sum(parts.values())
    return {"method": method, "size": size, "crop": crop, "gaussians": trainer.model.num_gaussians,
            "threads": threads, "steps": steps, "ms_per_it": 1000 * total / steps,
            "ms_per_it_median": 1000 * statistics.median(per_step), "ms": parts}


def markdown(rows: list[dict]) -> str:
    labels = list(dict.fromkeys(k for r in rows for k in r["ms"]))
    head = "| component (ms per iteration) | " + " | ".join(
        f"{r['method']} {r['size']}{' crop %g' % r['crop'] if r.get('crop', 1) < 1 else ''} {r['gaussians'] // 1000}k"
        for r in rows) + " |"
    lines = [head, "|---|" + "---|" * len(rows)]
    lines.append("| **whole iteration** (mean) | " + " | ".join(f"**{r['ms_per_it']:.1f}**" for r in rows) + " |")
    for k in labels:
        lines.append(f"| {k} | " + " | ".join(f"{r['ms'].get(k, 0.0):.1f}" for r in rows) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--methods", default="dtg,dtg-mlp", help="methods (comma-separated), or --variant names")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=METHOD:JSON",
                    help='a method with config overrides, e.g. \'dtg-nogeo=dtg:{"model.deform_geometry": []}\' (repeatable)')
    ap.add_argument("--sizes", default="160x120:10000,320x240:50000,640x480:100000",
                    help="W x H : Gaussians [@ crop fraction], comma-separated")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--from-run", type=Path, action="append", default=[], metavar="RUN",
                    help="time this trained run (recon run's output folder) as it ended (repeatable)")
    ap.add_argument("--progress", type=float, default=None,
                    help="with --from-run: hold the schedule here (default: where the run ended, at most 0.99)")
    ap.add_argument("--crop", type=float, default=None,
                    help="with --from-run: train on windows of F of each side (1: whole frames; default: as the run did)")
    args = ap.parse_args()
    variants = dict(parse_variant(v) for v in args.variant)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for run in args.from_run:
        if not (run / "checkpoints" / "latest.pt").exists():
            print(f"error: {run}: no checkpoints/latest.pt (a recon run output folder?)", file=sys.stderr)
            return 2
        rows.append(measure_run(run, args.progress, args.steps, args.warmup, args.threads, args.crop))
        print(f"{rows[-1]['method']}: {rows[-1]['gaussians']} Gaussians, {rows[-1]['ms_per_it']:.1f} ms/it", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for size in ([] if args.from_run else args.sizes.split(",")):
            size, _, crop = size.partition("@")
            wh, n = size.split(":")
            w, h = (int(v) for v in wh.split("x"))
            for method in args.methods.split(","):
                row = measure(method, variants.get(method, (method, {})), w, h, int(n), float(crop or 1), args.steps, args.warmup, args.threads,
                              Path(tmp))
                rows.append(row)
                print(f"{method} {w}x{h} crop {row['crop']:g} {row['gaussians']} Gaussians: "
                      f"{row['ms_per_it']:.1f} ms/it", flush=True)
    (args.out / "train_step.json").write_text(json.dumps(rows, indent=1))
    (args.out / "train_step.md").write_text(markdown(rows))
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
