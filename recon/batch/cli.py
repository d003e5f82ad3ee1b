"""`recon batch`: many `recon run`s (inputs x methods x seeds) as Ray tasks, locally or on a cluster."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from recon.batch.jobs import expand, parse_seeds
from recon.batch.summary import write_summary
from recon.config import METHODS
from rig.cli_format import positive_float, positive_int
from server.cli_options import add_serve_arguments, serve_from_args

EPILOG = """examples:
  recon batch data/a data/b --out runs/day1                      # dtg on two datasets, this machine
  recon batch sessions/* --out runs/day1 --method dtg,ed3dgs-thermal --seeds 0-2
  recon batch data/fam-* --out runs/fam --minutes 5 --fixed --address 10.0.0.5:6379   # on a Ray cluster
  recon batch data/a data/b --out runs/day1                      # again: finished jobs are skipped,
                                                                 # interrupted ones resume

RUNS/ holds one `recon run` folder per job (RUNS/INPUT/METHOD[-sSEED]/, with job.json and
log.txt), batch.json (every job's state, refreshed while running), and at the end summary.md,
summary.json and speed_vs_accuracy.png. Exit code 1 if any job failed (the others still ran).
A cluster: `ray start --head` on one machine, `ray start --address HEAD:6379` on the others,
thermal4d installed on each and INPUT/RUNS on a filesystem they all share (docs/batch.md)."""


def batch(args: argparse.Namespace) -> int:
    from recon.batch.ray_runner import run_batch
    from recon.run import input_kind

    methods = [m for part in args.method for m in part.split(",") if m] or ["dtg"]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"--method {','.join(unknown)}: not a method; choose from {', '.join(METHODS)}")
    inputs = [Path(p) for p in args.inputs]
    for path in inputs:
        input_kind(path)                    # a folder that is neither is refused before any job starts
    spec = {"iterations": args.iterations, "minutes": args.minutes, "fixed": args.fixed,
            "checkpoint_every": args.checkpoint_every, "max_gaussians": args.max_gaussians,
            "downscale": args.downscale, "frames": args.frames}
    seeds = parse_seeds(args.seeds) if args.seeds else None
    jobs = expand(inputs, methods, seeds, args.threads, spec)
    runs = Path(args.out)
    runs.mkdir(parents=True, exist_ok=True)
    log = lambda msg: print(f"recon batch: {msg}", file=sys.stderr, flush=True)  # noqa: E731
    log(f"{len(jobs)} jobs ({len(inputs)} inputs x {len(methods)} methods x {len(seeds or [None])} seeds) -> {runs}")
    handle = serve_from_args(args, batch_dir=runs)
    try:
        rows = run_batch(jobs, runs, address=args.address, memory_gb=args.memory_gb, retries=args.retries, log=log)
    finally:
        if handle:
            handle.stop()
    print(write_summary(runs, rows))
    failed = [r for r in rows if r["state"] == "failed"]
    print(f"{len(rows) - len(failed)} of {len(rows)} jobs finished; {runs / 'summary.md'}, "
          f"{runs / 'batch.json'}" + (f"; {len(failed)} failed (errors in batch.json and each job's log.txt)"
                                      if failed else ""))
    return 1 if failed else 0


def register(sub) -> None:
    p = sub.add_parser("batch", help="many runs (inputs x methods x seeds) as Ray tasks, here or on a cluster",
                       formatter_class=argparse.RawDescriptionHelpFormatter, description=__doc__, epilog=EPILOG)
    p.add_argument("inputs", nargs="+", metavar="DATASET_OR_SESSION", help="prepared datasets or rig sessions")
    p.add_argument("--out", required=True, metavar="RUNS", help="folder of the batch's runs (created)")
    p.add_argument("--method", action="append", default=[], metavar="M[,M...]",
                   help=f"methods (repeatable or comma-separated; default dtg): {', '.join(METHODS)}")
    p.add_argument("--seeds", help="training seeds, e.g. 0-3,7 (default: the method's seed, one job)")
    p.add_argument("--address", help="Ray cluster address HOST:PORT (default: a local Ray runtime on this machine)")
    p.add_argument("--threads", type=positive_int, default=1,
                   help="CPU threads per job, also its Ray CPU request (default 1: on few cores, jobs side by "
                        "side finish a batch sooner than one job on every core)")
    p.add_argument("--memory-gb", type=positive_float, default=2.0,
                   help="memory a job asks Ray for; Ray starts no more jobs on a node than fit (default 2)")
    p.add_argument("--retries", type=int, default=3,
                   help="times a job whose worker or node died is restarted, from its checkpoint (default 3)")
    g = p.add_argument_group("per job (as in `recon run`)")
    g.add_argument("--iterations", type=positive_int, help="exactly N iterations (default: until converged)")
    g.add_argument("--minutes", type=positive_float, help="wall-clock cap per job (recon run's default 15)")
    g.add_argument("--fixed", action="store_true", help="train exactly --minutes")
    g.add_argument("--checkpoint-every", type=positive_int, default=200,
                   help="iterations between checkpoints: what a lost node costs (default 200)")
    g.add_argument("--max-gaussians", type=positive_int, help="Gaussian budget")
    g.add_argument("--downscale", type=positive_int, help="a session's images at 1/N size (recon run's default 4)")
    g.add_argument("--frames", type=positive_int, help="a session's time steps")
    add_serve_arguments(p)
    p.set_defaults(func=batch)
