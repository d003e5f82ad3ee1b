"""What Ray costs a batch, and the batch's scale model checked on a two-node cluster.

    python bench/batch_overhead.py --out bench/results/batch

Four small jobs (four simulated family scenes, dtg, a fixed iteration count):
  back_to_back   `recon run --threads T` four times in a row (a process each, as a user would)
  batch_local    `recon batch --threads T` on a local Ray runtime with T CPUs: one job at a
                 time, the same schedule as back_to_back, so the difference is Ray's overhead
  cluster        the four jobs on a two-node Ray cluster on this machine (ray.cluster_utils,
                 one CPU per node, --threads 1: two jobs at a time)
  one_thread     one job alone with `recon run --threads 1`: the per-job cost of the scale model
Scale model: a batch of J jobs on W workers of one job's size takes about
ceil(J / W) x (per-job cost on that worker) + Ray's start-up; the cluster row checks it.
Writes overhead.json and overhead.md in --out.
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from recon.batch.jobs import expand  # noqa: E402
from recon.batch.ray_runner import run_batch  # noqa: E402
from recon.data.simulate import SimulateConfig, simulate_dataset  # noqa: E402


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--jobs", type=int, default=4)
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--size", default="160x120")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    w, h = (int(v) for v in args.size.split("x"))
    data = []
    for seed in range(args.jobs):
        path = args.out / "data" / f"fam{seed}"
        if not (path / "transforms.json").exists():
            simulate_dataset(path, SimulateConfig(variant="family-inside", frames=20, width=w, height=h, seed=200 + seed))
        data.append(path)
    recon = [sys.executable, "-m", "recon"]
    its = ["--iterations", str(args.iterations), "--seed", "0"]
    work = args.out / "work"
    subprocess.run(["rm", "-rf", str(work)], check=True)

    back = sum(timed(recon + ["run", str(d), "--out", str(work / "plain" / d.name), "--threads", str(args.threads)] + its)
               for d in data)
    one = timed(recon + ["run", str(data[0]), "--out", str(work / "one"), "--threads", "1"] + its)
    # a local runtime with T CPUs runs one T-thread job at a time: back_to_back's schedule
    t0 = time.perf_counter()
    rows = run_batch(expand(data, ["dtg"], [0], args.threads, {"iterations": args.iterations}), work / "local",
                     local_cpus=args.threads, log=lambda m: print(m, flush=True))
    local = time.perf_counter() - t0
    assert all(r["state"] == "done" for r in rows), rows

    import ray
    from ray.cluster_utils import Cluster
    t0 = time.perf_counter()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    cluster.add_node(num_cpus=1)
    ray.init(address=cluster.address, log_to_driver=False)
    cluster.wait_for_nodes()
    rows = run_batch(expand(data, ["dtg"], [0], 1, {"iterations": args.iterations}), work / "cluster",
                     log=lambda m: print(m, flush=True))
    two_node = time.perf_counter() - t0
    nodes = len({r["node"] for r in rows})
    ray.shutdown()
    cluster.shutdown()
    predicted = math.ceil(args.jobs / 2) * one
    result = {"jobs": args.jobs, "iterations": args.iterations, "threads": args.threads, "size": args.size,
              "back_to_back_s": round(back, 1), "batch_local_s": round(local, 1),
              "ray_overhead": round(local / back - 1, 3), "one_job_1_thread_s": round(one, 1),
              "cluster_2x1cpu_s": round(two_node, 1), "cluster_nodes_used": nodes,
              "scale_model_s": round(predicted, 1), "scale_model_error": round(two_node / predicted - 1, 3)}
    (args.out / "overhead.json").write_text(json.dumps(result, indent=1))
    (args.out / "overhead.md").write_text(
        f"| {args.jobs} jobs, dtg {args.iterations} it, {args.size} | wall s |\n|---|---|\n"
        f"| `recon run --threads {args.threads}` back to back | {back:.1f} |\n"
        f"| `recon batch --threads {args.threads}`, local Ray, {args.threads} CPUs | {local:.1f} "
        f"({100 * result['ray_overhead']:+.1f} %) |\n"
        f"| two-node cluster (1 CPU each), `--threads 1` | {two_node:.1f} (nodes used: {nodes}) |\n"
        f"| scale model: ceil({args.jobs}/2) x one job on 1 thread ({one:.1f} s) | {predicted:.1f} "
        f"({100 * result['scale_model_error']:+.1f} %) |\n")
    print((args.out / "overhead.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
