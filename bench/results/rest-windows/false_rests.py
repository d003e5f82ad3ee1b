"""The rest windows (paths.rest_windows, PathConfig overrides as JSON) of every moving path's
frames, before fit_track's rest_cost test, with how far the simulator's object really moved over
each: a window over a still object reads 0.000 m.

    python bench/results/rest-windows/false_rests.py '{"rest_px": 1.0}' DATA...
    python bench/results/rest-windows/false_rests.py --size '{"rest_px": 1.0}' DATA...   # -> size-trend.txt

--size: can the blob's size tell a rest from a slow move along the rays? Over each window's whole
frames, the still point's depths beside the true ones, and the trend of the object's size as the
still point implies it, log(blob diameter x depth / fx): its fitted change from the first to the
last frame (0 for a still ball) and residual, beside the same trend under the true depths (how far
the blob's own size strays from its object's: cut, heated, turned).
"""
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train import paths as P  # noqa: E402


def size_trend(ts, proj, px, w, fx, diam, truth):
    """Over one window's frames (times ts (T,), projections (T, 3, 4), pixels and weights (T, 2),
    focal lengths fx and blob diameters diam (T,), the object's true centres truth (T, 3)): the
    still point's depths (T,), the true depths (T,), the (change, residual) of log(diam x depth /
    fx) fitted linearly in time under the still point's depths, and that change under the true ones."""
    x = np.linalg.svd(P.dlt_rows(proj, px, w))[2][-1]
    depth = proj[:, 2, :3] @ (x[:3] / x[3]) + proj[:, 2, 3]
    true_depth = np.einsum('tj,tj->t', proj[:, 2, :3], truth) + proj[:, 2, 3]
    a = np.stack([np.ones_like(ts), ts - ts.mean()], 1)

    def trend(d):
        size = np.log(diam * d / fx)
        coef = np.linalg.lstsq(a, size, rcond=None)[0]
        return coef[1] * (ts[-1] - ts[0]), float(np.std(size - a @ coef))
    return depth, true_depth, trend(depth), trend(true_depth)[0]


torch.set_grad_enabled(False)
sizes = sys.argv[1] == "--size"
args = sys.argv[2:] if sizes else sys.argv[1:]
settings = P.PathConfig(**json.loads(args[0]))
for name in args[1:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o, scene = Oracle(meta['variant'], meta['seed']), Scene(load_dataset(d))
    for p in P.tracked_paths(scene, settings).moving:
        ts = np.array(sorted(p.seen))
        cams = [scene.views_at('thermal', t)[0].camera for t in ts]
        proj = np.stack([P.projection(c) for c in cams])
        px = np.stack([p.seen[t].centroid for t in ts])
        w = np.array([[float(not p.seen[t].cut[0]), float(not p.seen[t].cut[1])] for t in ts])
        truth = np.stack([[o.centre(k, t) for t in ts] for k in range(len(o.objects))])
        k = int(np.argmin(np.median(np.linalg.norm(p.at(torch.as_tensor(ts)).numpy()[None] - truth, axis=2), 1)))
        for t0, t1 in P.rest_windows(ts, proj, px, w, settings.rest_px, settings.rest_frames):
            sel = (ts >= t0) & (ts <= t1)
            if not sizes:
                print(f"{d.name} {o.objects[k].name}: window {t0:.2f}-{t1:.2f} ({sel.sum()} frames): "
                      f"the object moved {np.ptp(truth[k][sel], 0).max():.3f} m")
                continue
            sel &= ~np.array([p.seen[t].border for t in ts])
            diam = np.array([p.seen[t].diameter for t in ts])[sel]
            depth, true_depth, (change, resid), true_change = size_trend(
                ts[sel], proj[sel], px[sel], w[sel], np.array([c.fx for c in cams])[sel], diam, truth[k][sel])
            print(f"{d.name:20s} {o.objects[k].name:14s} {t0:.2f}-{t1:.2f} n={sel.sum():2d} moved "
                  f"{np.ptp(truth[k][sel], 0).max():.3f} m | depth {depth.min():.2f}-{depth.max():.2f} (true "
                  f"{true_depth.min():.2f}-{true_depth.max():.2f}) size change {change:+.3f} resid {resid:.3f} | "
                  f"true-depth change {true_change:+.3f} diam {diam.min():.1f}-{diam.max():.1f}")
