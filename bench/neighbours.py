"""k nearest neighbours of Gaussian positions: recon's KD-tree against the chunked distance matrix
it replaced (recon/dtg/neighbours.py).

    python bench/neighbours.py --out bench/results/neighbours.json

Uniform random points in a box (the k-NN graph of the embedding smoothness, k = 8, is rebuilt
whenever densification changes the Gaussian count), median seconds of --reps runs per size,
the two alternated; also the share of points whose neighbour sets differ.
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

from recon.dtg.neighbours import knn_indices  # noqa: E402


def matrix_knn(points: torch.Tensor, k: int, chunk: int = 2048) -> torch.Tensor:
    """The former recon.dtg.losses.knn_indices: chunked torch.cdist + topk."""
    out = []
    for start in range(0, points.shape[0], chunk):
        d2 = torch.cdist(points[start:start + chunk], points)
        out.append(d2.topk(k + 1, dim=1, largest=False).indices[:, 1:])
    return torch.cat(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--sizes", default="10000,30000,60000,100000")
    p.add_argument("--k", type=int, default=8)
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    records = []
    for n in (int(s) for s in args.sizes.split(",")):
        pts = torch.rand(n, 3, generator=torch.Generator().manual_seed(n))
        times = {"kd_tree": [], "matrix": []}
        for _ in range(args.reps):
            for name, fn in (("matrix", matrix_knn), ("kd_tree", knn_indices)):
                start = time.perf_counter()
                idx = fn(pts, args.k)
                times[name].append(time.perf_counter() - start)
                if name == "matrix":
                    ref = idx
        differ = float((knn_indices(pts, args.k).sort(1).values != ref.sort(1).values).any(1).float().mean())
        r = {"n": n, "k": args.k, "matrix_s": statistics.median(times["matrix"]),
             "kd_tree_s": statistics.median(times["kd_tree"]), "sets_differ": differ}
        records.append(r)
        print(f"n={n}: matrix {r['matrix_s']:.3f} s, KD-tree {r['kd_tree_s']:.4f} s, "
              f"neighbour sets differ for {100 * differ:.3f} % of points", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"threads": args.threads, "records": records}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
