"""Per seed, method A -> method B from a bench/table.py table.json: thermal MAE K | moving-region
MAE K | moving-hot MAE K | RGB PSNR dB | guard events; then per scene the medians and on how many
seeds B's thermal MAE is lower. With several training seeds per scene seed (table.py
--train-seeds) each value is their mean, each seed's thermal MAE is followed by its runs' range
[lowest-highest] per arm, and the last line also counts the seeds where every B run is lower than
every A run (a difference no training seed's spread explains).

    python bench/results/still-first/paired.py TABLE.json A B
"""
import json
import statistics
import sys

table, a, b = json.load(open(sys.argv[1])), sys.argv[2], sys.argv[3]
groups: dict = {}
for r in table["per_run"]:
    groups.setdefault((r["scene"], r["seed"], r["method"]), []).append(r)
keys = ("mae_k_thermal", "mae_k_moving", "mae_k_moving_hot", "psnr_rgb")


def mean(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return statistics.fmean(vals) if vals else None


def value_range(rows: list[dict], key: str) -> tuple[float, float]:
    vals = [r[key] for r in rows if r.get(key) is not None] or [float("nan")]   # an RGB-only run: no thermal
    return min(vals), max(vals)


runs = {k: {**{key: mean(rows, key) for key in keys}, "events": sum(r["events"] for r in rows),
            "range": value_range(rows, "mae_k_thermal"), "n": len(rows)}
        for k, rows in groups.items()}
repeated = any(v["n"] > 1 for v in runs.values())
fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
spread = lambda v: f" [{v['range'][0]:.2f}-{v['range'][1]:.2f}]" if v["n"] > 1 else ""  # noqa: E731
print(f"per seed, {a} -> {b}: thermal MAE K | moving-region MAE K | moving-hot MAE K | RGB PSNR dB | guard events"
      + ("; each a mean over training seeds, [range] of thermal MAE" if repeated else ""))
for scene in sorted({s for s, _, _ in runs}):
    seeds = sorted(seed for s, seed, m in runs if s == scene and m == a and (s, seed, b) in runs)
    for seed in seeds:
        x, y = runs[scene, seed, a], runs[scene, seed, b]
        cells = [f"{fmt(x[keys[0]])}{spread(x)} -> {fmt(y[keys[0]])}{spread(y)}",
                 *(f"{fmt(x[k])} -> {fmt(y[k])}" for k in keys[1:])]
        print(f"{scene} {seed}: " + " | ".join(cells) + f" | {x['events']}/{y['events']}")
    # a seed without a region (no moving-hot pixels: None) has no value in that median
    med = {m: [statistics.median([v for s in seeds if (v := runs[scene, s, m][k]) is not None] or [float("nan")])
               for k in keys] for m in (a, b)}
    lower = sum(runs[scene, s, b]["mae_k_thermal"] < runs[scene, s, a]["mae_k_thermal"] for s in seeds)
    clear = (f"; every {b} run below every {a} run on "
             f"{sum(runs[scene, s, b]['range'][1] < runs[scene, s, a]['range'][0] for s in seeds)}, above on "
             f"{sum(runs[scene, s, b]['range'][0] > runs[scene, s, a]['range'][1] for s in seeds)}") if repeated else ""
    print(f"{scene} medians: " + " | ".join(f"{p:.2f} -> {q:.2f}" for p, q in zip(med[a], med[b]))
          + f"; thermal MAE lower on {lower} of {len(seeds)}{clear}")
