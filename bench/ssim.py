"""SSIM as a training loss: its analytic backward against autograd through the SSIM map.

    python bench/ssim.py --out bench/results/ssim.json

For each size, (1 - SSIM) of an RGB render-sized tensor against a target, forward + backward,
median ms over --reps after a warm-up, the two implementations alternated for --rounds rounds
(this host's load varies by 10-20 % minute to minute, so a paired minimum is reported beside
every round's median). `recon.eval.metrics.ssim` (no mask) is what training calls;
`ssim_map(...).mean()` is the same value with autograd recording every op (what ssim() was).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

from recon.eval.metrics import ssim, ssim_map  # noqa: E402


def _median_ms(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - start))
    return statistics.median(times)


def measure(width: int, height: int, reps: int, rounds: int) -> dict:
    gen = torch.Generator().manual_seed(0)
    leaf = torch.rand(height, width, 3, generator=gen, requires_grad=True)
    target = torch.rand(height, width, 3, generator=gen)

    def analytic():
        (1 - ssim(leaf * 1.0, target)).backward()  # * 1.0: a non-leaf, like a render

    def autograd_map():
        (1 - ssim_map(leaf * 1.0, target).mean()).backward()

    runs = {"analytic": [], "autograd": []}
    for _ in range(rounds):
        runs["autograd"].append(_median_ms(autograd_map, reps))
        runs["analytic"].append(_median_ms(analytic, reps))
    return {"size": f"{width}x{height}", "rounds": runs,
            "autograd_ms": min(runs["autograd"]), "analytic_ms": min(runs["analytic"]),
            "speedup": min(runs["autograd"]) / min(runs["analytic"])}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="JSON file to write")
    p.add_argument("--sizes", default="160x120,320x240,640x480")
    p.add_argument("--reps", type=int, default=25)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    records = []
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        r = measure(w, h, args.reps, args.rounds)
        records.append(r)
        print(f"{r['size']}: fwd+bwd autograd {r['autograd_ms']:.2f} ms, analytic {r['analytic_ms']:.2f} ms "
              f"({r['speedup']:.1f}x)", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"threads": args.threads, "reps": args.reps, "records": records}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
