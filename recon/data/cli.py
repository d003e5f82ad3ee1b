"""`recon simulate`: write a prepared dataset rendered from the simulated world."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from recon.data.simulate import SimulateConfig, simulate_dataset
from rig.sim import FAMILY_VARIANTS, VARIANTS
from rig.cli_format import positive_int

EPILOG = """\
examples:
  recon simulate data/sim --frames 30 --size 160x120
  recon simulate data/dark --variant dark --frames 120 --size 320x240 --seed 3 --jobs 2
  recon simulate data/one-rig --rigs 1 --explicit-splits

Each time step gives, per rig, one RGB and one thermal frame (camera names cam0, cam1; cam1 is
the test camera by the dataset format's default rule). Also written: points3d.ply (sparse
SfM-like points seen by cam0) and sim_meta.json (variant, seed, rig extrinsic, true thermal
intrinsics). Same arguments, same bytes.
"""


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 160x120, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def register(sub) -> None:
    p = sub.add_parser("simulate", help="write a prepared dataset from the simulated RGB-thermal world",
                       description=__doc__, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    d = SimulateConfig()
    p.add_argument("out", type=Path, metavar="OUT", help="new (or empty) output folder")
    p.add_argument("--variant", choices=VARIANTS + FAMILY_VARIANTS, default=d.variant,
                   help=f"scene variant (default: {d.variant}); family-<case>: a new scene per --seed "
                        f"(rig/sim/family.py)")
    p.add_argument("--frames", type=positive_int, default=d.frames,
                   help=f"time steps over the 10 s script (default: {d.frames})")
    p.add_argument("--size", type=_size, default=(d.width, d.height), metavar="WxH",
                   help=f"image size of both modalities (default: {d.width}x{d.height})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"textures, hand shake, noise (default: {d.seed})")
    p.add_argument("--rigs", type=int, choices=(1, 2), default=d.rigs, help=f"handheld rigs (default: {d.rigs})")
    p.add_argument("--points", type=int, default=d.points, help=f"initial sparse points (default: {d.points})")
    p.add_argument("--explicit-splits", action="store_true",
                   help="also write train_filenames/test_filenames (cam1 = test)")
    p.add_argument("--jobs", type=int, default=d.jobs, help=f"worker processes (default: {d.jobs})")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.out.exists() and any(args.out.iterdir()):
        print(f"recon simulate: {args.out} is not empty; choose a new folder", file=sys.stderr)
        return 2
    if args.frames < 1 or args.jobs < 1 or args.points < 0:
        print("recon simulate: --frames and --jobs must be >= 1, --points >= 0", file=sys.stderr)
        return 2
    cfg = SimulateConfig(args.variant, args.frames, *args.size, args.seed, args.rigs, args.points,
                         args.explicit_splits, args.jobs)
    start = time.perf_counter()

    def progress(done: int, total: int) -> None:
        if done == total or done % max(1, total // 20) == 0:
            print(f"  step {done}/{total}  {time.perf_counter() - start:.1f} s", flush=True)

    print(f"simulating {cfg.variant!r}: {cfg.frames} steps x {cfg.rigs} rig(s) x (RGB + thermal) "
          f"at {cfg.width}x{cfg.height}, seed {cfg.seed}", flush=True)
    path = simulate_dataset(args.out, cfg, progress)
    print(f"wrote {path} ({2 * cfg.rigs * cfg.frames} frames) in {time.perf_counter() - start:.1f} s")
    return 0
