"""Paired timing of a dtg iteration with the bodies' motion in torch ops (the reference, as before
614f109) and with the native kernels, alternated in blocks of 20 iterations on one trainer (this
host drifts 20 % from minute to minute; alternating cancels it).

    python bench/results/native-motion/paired.py RUN [ROUNDS] > bench/results/native-motion/paired.txt

RUN: a finished `recon run` / bench/table.py run (its latest checkpoint, resumed as
bench/train_step.py --from-run does, 2 threads)."""
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]
import recon  # noqa: E402,F401
from recon.dtg import motion  # noqa: E402
from train_step import resume_held, warm_images  # noqa: E402

native_apply = motion.apply_motion


def reference_apply(means, quats, basis, gate, bases, t):
    if not bool((basis > 0).any()):
        return means, quats
    rot, trans = bases.at(t)
    return motion.apply_motion_reference(means, quats, basis, gate,
                                         motion.body_transforms_reference(rot, trans, bases.pivots))


def use(which: str) -> None:
    import recon.dtg.model as model
    fn = native_apply if which == "native" else reference_apply
    motion.apply_motion = model.apply_motion = fn


run = Path(sys.argv[1])
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 8
trainer, p = resume_held(run, threads=2)
warm_images(trainer.scene)
for _ in range(20):
    trainer.step()
times = {"reference": [], "native": []}
for r in range(rounds):
    for which in ("reference", "native") if r % 2 == 0 else ("native", "reference"):
        use(which)
        t0 = time.perf_counter()
        for _ in range(20):
            trainer.step()
        times[which].append(1000 * (time.perf_counter() - t0) / 20)
print(f"{run} at progress {p:.2f}, {trainer.model.num_gaussians} Gaussians, "
      f"{int((trainer.model.gaussians['motion_basis'] > 0).sum())} on bodies; ms per iteration, blocks of 20:")
for which, ms in times.items():
    print(f"  {which:9s} " + " ".join(f"{m:5.1f}" for m in ms) + f"   median {statistics.median(ms):.1f}")
pairs = [n / o for n, o in zip(times["native"], times["reference"])]
print(f"  native / reference per round: median {statistics.median(pairs):.3f} (" +
      " ".join(f"{x:.3f}" for x in pairs) + ")")
