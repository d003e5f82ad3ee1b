"""The native rasterizer's stages on a trained model, at its cameras or a multiple of their size.

    python bench/raster_trained.py --ply RUN/export/model.ply --transforms DATA/transforms.json \
        --scale 4 --out /tmp/rt.json
    python bench/raster_trained.py --ply ... --transforms ... --scale 1,4 --rounds 3 \
        --against /tmp/old-checkout --out /tmp/rt.json

bench/rasterizer.py's workload is round Gaussians on a sphere; a trained model's footprints are
long and tilted (a family model: 10-20 % of its Gaussians ten times longer than wide), which is
where tile lists and pixel boxes waste most. The model's Gaussians are drawn as they are in the
PLY (canonical positions, opacity sigmoid, colour = SH DC) from frames 0, 10, 20, 30 of the
transforms.json, with focal lengths, principal point and size times --scale. Each measurement is
median ms over --reps renders of those four views after one warm-up: binning and sort, compositing
(forward minus binning), compositing's backward (image and alpha gradients of ones), and the number
of Gaussian-tile pairs.

--against DIR: another checkout with a built `recon/splat/_native` (e.g. `git worktree add DIR
OLD_COMMIT`, then build or copy its `.so`). Each of --rounds runs this checkout and DIR in turn, in
fresh processes, so that the host's drift lands on both alike; the JSON keeps every round.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FRAMES = (0, 10, 20, 30)


def measure(ply: Path, transforms: Path, scale: int, reps: int, threads: int) -> dict:
    """Median ms of binning, compositing and its backward over reps renders of each view."""
    import numpy as np
    import torch

    from recon.dtg.gaussians import SH_C0
    from recon.splat import _native
    from recon.splat.cli import frame_camera
    from recon.splat.ply import read_gaussians_ply
    from recon.splat.rasterization import intrinsics, project

    g = read_gaussians_ply(ply)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
    opacities = torch.sigmoid(t(g.opacity_logits))
    colors = (t(g.sh[:, 0]) * SH_C0 + 0.5).contiguous()
    frames = json.loads(transforms.read_text())["frames"]
    views = []
    with torch.no_grad():
        for f in (f for f in FRAMES if f < len(frames)):
            c = frame_camera(transforms, f)
            w, h = c.width * scale, c.height * scale
            cam = intrinsics(c.fx * scale, c.fy * scale, c.cx * scale, c.cy * scale, w, h, 0.01)
            m2, con, dep, rad, col = project(t(g.means), t(g.quats), t(g.log_scales), opacities, colors,
                                             c.viewmat, cam, None, threads)
            vis = rad > 0
            inputs = [x[vis].contiguous().numpy() for x in (m2, con, col, opacities, dep)]
            views.append((inputs + [np.ones(int(vis.sum()), np.int32)], w, h))
    times = {"binning": [], "composite": [], "composite_backward": [], "tile_pairs": []}
    for rep in range(reps + 1):
        for inputs, w, h in views:
            t0 = time.perf_counter()
            image, alpha, _, final_t, last, tx, ty, offsets, ids, boxes, bin_s = _native.rasterize_forward(
                *inputs, w, h, 1 << 28, threads)
            t1 = time.perf_counter()
            grads = (np.ones_like(image), np.ones_like(alpha), np.zeros_like(alpha))
            _native.rasterize_backward(*inputs, w, h, final_t, last, tx, ty, offsets, ids, boxes, *grads, threads)
            t2 = time.perf_counter()
            if rep:  # the first is a warm-up
                times["binning"].append(1e3 * bin_s)
                times["composite"].append(1e3 * (t1 - t0 - bin_s))
                times["composite_backward"].append(1e3 * (t2 - t1))
                times["tile_pairs"].append(len(ids))
    out = {k: round(statistics.median(v), 3) for k, v in times.items()}
    out["total"] = round(out["binning"] + out["composite"] + out["composite_backward"], 3)
    out["visible"] = int(len(views[0][0][0]))
    out["size"] = f"{views[0][1]}x{views[0][2]}"
    return out


def _run_in(checkout: Path, args, scale: int) -> dict:
    """measure() in a fresh process that imports recon from checkout."""
    code = (f"import sys, json; sys.path.insert(0, {str(checkout)!r}); sys.path.insert(1, {str(ROOT / 'bench')!r}); "
            f"from raster_trained import measure; from pathlib import Path; "
            f"print(json.dumps(measure(Path({str(args.ply)!r}), Path({str(args.transforms)!r}), {scale}, "
            f"{args.reps}, {args.threads})))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=checkout)
    if run.returncode != 0:
        raise SystemExit(f"raster_trained: measuring in {checkout} failed:\n{run.stderr}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--ply", type=Path, required=True, help="a trained model (RUN/export/model.ply)")
    p.add_argument("--transforms", type=Path, required=True, help="its dataset's transforms.json")
    p.add_argument("--scale", default="1", help="comma-separated multiples of the cameras' size (default 1)")
    p.add_argument("--reps", type=int, default=8)
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--against", type=Path, help="another checkout, measured in turn with this one")
    p.add_argument("--out", type=Path, required=True, help="JSON of every round")
    args = p.parse_args(argv)
    for path in (args.ply, args.transforms):
        if not path.is_file():
            p.error(f"{path}: no such file")
    checkouts = {"this": ROOT} | ({"against": args.against.resolve()} if args.against else {})
    rounds = []
    for r in range(args.rounds):
        for scale in (int(s) for s in args.scale.split(",")):
            for name, checkout in checkouts.items():
                rec = {"round": r, "scale": scale, "checkout": name, "path": str(checkout)} | _run_in(checkout, args, scale)
                rounds.append(rec)
                print(f"round {r} {rec['size']} {name:8s} binning {rec['binning']:.2f} composite {rec['composite']:.2f} "
                      f"backward {rec['composite_backward']:.2f} total {rec['total']:.2f} ms, pairs {rec['tile_pairs']}",
                      flush=True)
    summary = {}
    for name in checkouts:
        for scale in {r["scale"] for r in rounds}:
            rs = [r for r in rounds if r["checkout"] == name and r["scale"] == scale]
            summary[f"{name} x{scale}"] = {k: round(statistics.median(r[k] for r in rs), 3)
                                           for k in ("binning", "composite", "composite_backward", "total", "tile_pairs")}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"ply": str(args.ply), "transforms": str(args.transforms), "rounds": rounds,
                                    "median": summary}, indent=1))
    for k, v in summary.items():
        print(k, v)
    return 0


if __name__ == "__main__":
    sys.exit(main())
