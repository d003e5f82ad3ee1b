"""Render speed of the simulated world (rig.sim): RGB and thermal frames at several sizes.

    PYTHONPATH=. python bench/sim_render.py --out bench/results/sim_render.json [--repeats 9]

Writes a list of records {"size", "ss", "rgb_ms", "thermal_ms", "pair_ms", "load_avg_1min"}
(medians over `repeats` frames at different times and rigs, after one warm-up frame; the
1-minute load average when the size was done). The machine is shared, so re-run on a quiet
machine for final numbers. The committed result: bench/results/sim_render.json.
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from rig.sim import make_world
from rig.sim.world import supersampling


def _time_frame(world, size, t, rig):
    c2w_rgb, c2w_th = world.rig_pose(rig, t)
    ki, kt = world.rig_config.rgb.scaled(*size), world.rig_config.thermal.scaled(*size)
    t0 = time.perf_counter()
    world.render_rgb(c2w_rgb, ki.fx, ki.fy, ki.cx, ki.cy, *size, t, rng=np.random.default_rng(0))
    t1 = time.perf_counter()
    world.thermal_counts(world.render_temperature(c2w_th, kt.fx, kt.fy, kt.cx, kt.cy, *size, t),
                         np.random.default_rng(0))
    return (t1 - t0) * 1e3, (time.perf_counter() - t1) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="JSON file to write")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--variant", default="default")
    args = parser.parse_args()
    world = make_world(args.variant, 0)
    records = []
    for size in [(160, 120), (320, 240), (640, 480)]:
        _time_frame(world, size, 0.0, 0)
        times = np.array([_time_frame(world, size, 10 * i / args.repeats, i % 2)
                          for i in range(args.repeats)])
        rec = {"size": f"{size[0]}x{size[1]}", "ss": supersampling(*size),
               "rgb_ms": float(np.median(times[:, 0])), "thermal_ms": float(np.median(times[:, 1])),
               "pair_ms": float(np.median(times.sum(axis=1))), "load_avg_1min": round(os.getloadavg()[0], 2)}
        print(rec, flush=True)
        records.append(rec)
    with open(args.out, "w") as f:
        json.dump(records, f, indent=1)


if __name__ == "__main__":
    main()
