"""Equal time, per seed: dtg against ed3dgs-thermal on thermal MAE and against ed3dgs-rgb on RGB
PSNR, from one bench/table.py table.json holding the three methods (a failed run has no metrics and
is listed as failed; a median is over the seeds both methods finished).

    python bench/results/equal-time/compare.py TABLE.json
"""
import json
import statistics
import sys

runs = {(r["scene"], r["seed"], r["method"]): r for r in json.load(open(sys.argv[1]))["per_run"]}
# (baseline, metric, label, whether dtg's value a beats the baseline's b)
pairs = (("ed3dgs-thermal", "mae_k_thermal", "thermal MAE K", lambda a, b: a < b),
         ("ed3dgs-rgb", "psnr_rgb", "RGB PSNR dB", lambda a, b: a > b))
fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731


def value(scene, seed, method, key):
    r = runs.get((scene, seed, method))
    return None if r is None else r.get(key)


for scene in sorted({s for s, _, _ in runs}):
    seeds = sorted({seed for s, seed, _ in runs if s == scene})
    for other, key, label, better in pairs:
        print(f"{scene}, {label}: dtg vs {other} (dtg's iterations / {other}'s)")
        both, wins = [], 0
        for seed in seeds:
            a, b = value(scene, seed, "dtg", key), value(scene, seed, other, key)
            if a is None or b is None:
                print(f"  {seed}: {fmt(a)} vs {fmt(b)} (failed or missing)")
                continue
            both.append((a, b))
            wins += better(a, b)
            its = [value(scene, seed, m, "iterations") for m in ("dtg", other)]
            print(f"  {seed}: {a:.2f} vs {b:.2f}  ({its[0]} / {its[1]} it)")
        if both:
            print(f"  median over {len(both)} seeds: {statistics.median(a for a, _ in both):.2f} vs "
                  f"{statistics.median(b for _, b in both):.2f}; dtg better on {wins} of {len(both)}")
