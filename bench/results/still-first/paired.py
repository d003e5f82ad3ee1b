"""Per seed, method A -> method B from a bench/table.py table.json: thermal MAE K | moving-region
MAE K | moving-hot MAE K | RGB PSNR dB | guard events; then per scene the medians and on how many
seeds B's thermal MAE is lower.

    python bench/results/still-first/paired.py TABLE.json A B
"""
import json
import statistics
import sys

table, a, b = json.load(open(sys.argv[1])), sys.argv[2], sys.argv[3]
runs = {(r["scene"], r["seed"], r["method"]): r for r in table["per_run"]}
fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
keys = ("mae_k_thermal", "mae_k_moving", "mae_k_moving_hot", "psnr_rgb")
print(f"per seed, {a} -> {b}: thermal MAE K | moving-region MAE K | moving-hot MAE K | RGB PSNR dB | guard events")
for scene in sorted({s for s, _, _ in runs}):
    seeds = sorted(seed for s, seed, m in runs if s == scene and m == a and (s, seed, b) in runs)
    for seed in seeds:
        x, y = runs[scene, seed, a], runs[scene, seed, b]
        print(f"{scene} {seed}: " + " | ".join(f"{fmt(x[k])} -> {fmt(y[k])}" for k in keys)
              + f" | {x['events']}/{y['events']}")
    # a seed without a region (no moving-hot pixels: None) has no value in that median
    med = {m: [statistics.median([v for s in seeds if (v := runs[scene, s, m][k]) is not None] or [float("nan")])
               for k in keys] for m in (a, b)}
    lower = sum(runs[scene, s, b]["mae_k_thermal"] < runs[scene, s, a]["mae_k_thermal"] for s in seeds)
    print(f"{scene} medians: " + " | ".join(f"{p:.2f} -> {q:.2f}" for p, q in zip(med[a], med[b]))
          + f"; thermal MAE lower on {lower} of {len(seeds)}")
