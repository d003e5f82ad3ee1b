"""Whole training steps with this checkout's native kernels against another build's, in one process.

    python bench/step_ab.py --from-run RUN --against /tmp/old-checkout --out /tmp/ab.json
    python bench/step_ab.py --from-run RUN --against DIR --crop 1 --rounds 20 --block 5 --out ab.json

A shared 2-core host drifts by more than a few per cent from one minute to the next, so two
builds timed one after the other (bench/train_step.py twice) cannot show a change of that size.
Here one trained run (RUN/checkpoints/latest.pt on its dataset, the schedule held where it ended,
at most p 0.99) is resumed once, and blocks of --block steps alternate between this checkout's
`recon.splat._native` and `recon.eval._native` and those built in --against (e.g. `git worktree
add DIR OLD_COMMIT`, then `python setup.py build_ext --inplace` there); which build goes first
alternates per round. Both builds train the same model in turn, so the drift lands on both
alike. Writes per-round ms per step, the medians, and in how many rounds this build was faster.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--from-run", type=Path, required=True, metavar="RUN")
    ap.add_argument("--against", type=Path, required=True, metavar="DIR")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--crop", type=float, default=None, help="windows of F of each side (1: whole frames; default: as the run)")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--block", type=int, default=10, help="steps per build per round")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    from raster_trained import load_native
    from recon.eval import metrics
    from recon.splat import _functions
    from train_step import resume_held, warm_images

    builds = {"this": (_functions._native, metrics._native),
              "against": (load_native(args.against, "splat"), load_native(args.against, "eval"))}
    trainer, p = resume_held(args.from_run, args.threads, crop=args.crop)
    warm_images(trainer.scene)
    for _ in range(3):
        trainer.step()
    ms = {k: [] for k in builds}
    for r in range(args.rounds):
        for name in (("this", "against") if r % 2 == 0 else ("against", "this")):
            _functions._native, metrics._native = builds[name]
            start = time.perf_counter()
            for _ in range(args.block):
                trainer.step()
            ms[name].append(1000 * (time.perf_counter() - start) / args.block)
        print(f"round {r + 1}/{args.rounds}: this {ms['this'][-1]:.1f} ms, against {ms['against'][-1]:.1f} ms",
              flush=True)
    _functions._native, metrics._native = builds["this"]
    faster = sum(a < b for a, b in zip(ms["this"], ms["against"]))
    result = {"run": str(args.from_run), "against": str(args.against), "crop": trainer.cfg.crop,
              "gaussians": trainer.model.num_gaussians, "progress": p, "block": args.block,
              "ms_per_step": ms, "median_this": statistics.median(ms["this"]),
              "median_against": statistics.median(ms["against"]), "this_faster_rounds": faster}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(f"this build median {result['median_this']:.1f} ms, {args.against} {result['median_against']:.1f} ms; "
          f"this faster in {faster} of {args.rounds} rounds -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
