"""The native rasterizer's stages on a trained model (or the synthetic workload), two builds alternated.

    python bench/raster_trained.py --ply RUN/export/model.ply --transforms DATA/transforms.json \
        --scale 4 --out /tmp/rt.json
    python bench/raster_trained.py --ply ... --transforms ... --scale 1,4 --rounds 3 \
        --against /tmp/old-checkout --out /tmp/rt.json
    python bench/raster_trained.py --workload 200000 --against /tmp/old-checkout --out /tmp/rt.json

bench/rasterizer.py's workload is round Gaussians on a sphere; a trained model's footprints are
long and tilted (a family model: 10-20 % of its Gaussians ten times longer than wide), which is
where tile lists and pixel boxes waste most. The model's Gaussians are drawn as they are in the
PLY (canonical positions, opacity sigmoid, colour = SH DC) from frames 0, 10, 20, 30 of the
transforms.json, with focal lengths, principal point and size times --scale. `--workload N`
draws bench/rasterizer.py's N-Gaussian scene from its 20 views instead. Each measurement is
median ms over --reps renders of those views after one warm-up: binning and sort, compositing
(forward minus binning), compositing's backward (image and alpha gradients of ones), and the number
of Gaussian-tile pairs.

--against DIR: another checkout with a built `recon/splat/_native` (e.g. `git worktree add DIR
OLD_COMMIT`, then build or copy its `.so`). Both builds are loaded into this one process and called
in turn on every view (which goes first alternates), so the host's drift, large on a shared
2-core machine, lands on both alike; `paired` in the JSON is the median over those calls of
this build's total / DIR's, and the images of the two builds are compared.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FRAMES = (0, 10, 20, 30)
STAGES = ("binning", "composite", "composite_backward", "total")


def load_native(checkout: Path, package: str = "splat"):
    """recon/<package>/_native built in checkout, loaded under its own package name beside ours."""
    found = sorted((checkout / "recon" / package).glob("_native*.so"))
    if not found:
        raise SystemExit(f"{checkout}/recon/{package} has no built _native*.so "
                         "(run `python setup.py build_ext --inplace` there)")
    spec = importlib.util.spec_from_file_location(f"against_{package}_{abs(hash(str(checkout)))}._native", found[0])
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def model_views(ply: Path, transforms: Path, scale: int, threads: int) -> list[tuple]:
    """Per frame of FRAMES: ([means2d, conics, colors, opacities, depths, radii] of the visible
    Gaussians as numpy arrays, width, height)."""
    import numpy as np
    import torch

    from recon.dtg.gaussians import SH_C0
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
    return views


def workload_views(n: int, threads: int) -> list[tuple]:
    """bench/rasterizer.py's scene of n Gaussians, as model_views()."""
    import numpy as np
    import torch

    sys.path.insert(0, str(ROOT / "bench"))
    from rasterizer import _raster_inputs
    from splat_workload import make_workload

    w = make_workload(n)
    return [([x.numpy() for x in v] + [np.ones(len(v[0]), np.int32)], w.width, w.height)
            for v in _raster_inputs(w, torch, threads)]


def time_render(native, inputs, w: int, h: int, threads: int) -> tuple[dict, object]:
    """One forward and backward of native on a view: ms per stage, and the image."""
    import numpy as np

    t0 = time.perf_counter()
    image, alpha, _, final_t, last, tx, ty, offsets, ids, boxes, bin_s = native.rasterize_forward(
        *inputs, w, h, 1 << 28, threads)
    t1 = time.perf_counter()
    grads = (np.ones_like(image), np.ones_like(alpha), np.zeros_like(alpha))
    native.rasterize_backward(*inputs, w, h, final_t, last, tx, ty, offsets, ids, boxes, *grads, threads)
    t2 = time.perf_counter()
    ms = {"binning": 1e3 * bin_s, "composite": 1e3 * (t1 - t0 - bin_s), "composite_backward": 1e3 * (t2 - t1)}
    ms["total"] = sum(ms.values())
    ms["tile_pairs"] = len(ids)
    return ms, image


def measure(views: list[tuple], natives: dict, reps: int, threads: int) -> dict:
    """Per build: median ms of each stage over reps renders of every view (after a warm-up), the
    builds called in turn on each view; with two builds also `paired` and `max_image_diff`."""
    import numpy as np

    times = {name: {k: [] for k in STAGES + ("tile_pairs",)} for name in natives}
    ratios, image_diff = [], 0.0
    names = list(natives)
    for rep in range(reps + 1):
        for i, (inputs, w, h) in enumerate(views):
            order = names if (rep + i) % 2 == 0 else names[::-1]
            done = {name: time_render(natives[name], inputs, w, h, threads) for name in order}
            if rep == 0:  # warm-up
                continue
            for name, (ms, _) in done.items():
                for k, v in ms.items():
                    times[name][k].append(v)
            if len(names) == 2:
                ratios.append(done[names[0]][0]["total"] / done[names[1]][0]["total"])
                image_diff = max(image_diff, float(np.abs(done[names[0]][1] - done[names[1]][1]).max()))
    out = {name: {k: round(statistics.median(v), 3) for k, v in t.items()} for name, t in times.items()}
    if len(names) == 2:
        out["paired"] = round(statistics.median(ratios), 4)
        out["max_image_diff"] = image_diff
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--ply", type=Path, help="a trained model (RUN/export/model.ply)")
    p.add_argument("--transforms", type=Path, help="its dataset's transforms.json")
    p.add_argument("--workload", type=int, help="instead of --ply: bench/rasterizer.py's scene of N Gaussians")
    p.add_argument("--scale", default="1", help="comma-separated multiples of the cameras' size (default 1)")
    p.add_argument("--reps", type=int, default=8)
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--against", type=Path, help="another checkout, measured in turn with this one")
    p.add_argument("--out", type=Path, required=True, help="JSON of every round")
    args = p.parse_args(argv)
    if (args.ply is None) == (args.workload is None):
        p.error("give either --ply with --transforms, or --workload N")
    if args.ply is not None:
        for path in (args.ply, args.transforms):
            if path is None or not path.is_file():
                p.error(f"{path}: no such file (--ply needs --transforms)")
    sys.path.insert(0, str(ROOT))
    from recon.splat import _native

    natives = {"this": _native} | ({"against": load_native(args.against.resolve())} if args.against else {})
    scales = [1] if args.workload else [int(s) for s in args.scale.split(",")]
    rounds = []
    for scale in scales:
        views = (workload_views(args.workload, args.threads) if args.workload
                 else model_views(args.ply, args.transforms, scale, args.threads))
        for r in range(args.rounds):
            res = measure(views, natives, args.reps, args.threads)
            for name in natives:
                rec = {"round": r, "scale": scale, "checkout": name, "size": f"{views[0][1]}x{views[0][2]}",
                       "visible": len(views[0][0][0])} | res[name]
                rounds.append(rec)
                print(f"round {r} {rec['size']} {name:8s} binning {rec['binning']:.2f} composite {rec['composite']:.2f} "
                      f"backward {rec['composite_backward']:.2f} total {rec['total']:.2f} ms, pairs {rec['tile_pairs']}",
                      flush=True)
            if "paired" in res:
                rounds.append({"round": r, "scale": scale, "paired": res["paired"], "max_image_diff": res["max_image_diff"]})
                print(f"round {r} paired this / against {res['paired']:.3f}, images differ by <= {res['max_image_diff']:.2g}")
    summary = {}
    for name in natives:
        for scale in scales:
            rs = [r for r in rounds if r.get("checkout") == name and r["scale"] == scale]
            summary[f"{name} x{scale}"] = {k: round(statistics.median(r[k] for r in rs), 3) for k in STAGES + ("tile_pairs",)}
    for scale in scales:
        ps = [r["paired"] for r in rounds if "paired" in r and r["scale"] == scale]
        if ps:
            summary[f"paired x{scale}"] = round(statistics.median(ps), 4)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"ply": str(args.ply) if args.ply else None, "workload": args.workload,
                                    "transforms": str(args.transforms) if args.transforms else None,
                                    "against": str(args.against) if args.against else None,
                                    "rounds": rounds, "median": summary}, indent=1))
    for k, v in summary.items():
        print(k, v)
    return 0


if __name__ == "__main__":
    sys.exit(main())
