"""The rest windows (paths.rest_windows, PathConfig overrides as JSON) of every moving path's
frames, before fit_track's rest_cost test, with how far the simulator's object really moved over
each: a window over a still object reads 0.000 m.

    python bench/results/rest-windows/false_rests.py '{"rest_px": 1.0}' DATA...
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

torch.set_grad_enabled(False)
settings = P.PathConfig(**json.loads(sys.argv[1]))
for name in sys.argv[2:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o, scene = Oracle(meta['variant'], meta['seed']), Scene(load_dataset(d))
    for p in P.tracked_paths(scene, settings).moving:
        ts = np.array(sorted(p.seen))
        proj = np.stack([P.projection(scene.views_at('thermal', t)[0].camera) for t in ts])
        px = np.stack([p.seen[t].centroid for t in ts])
        w = np.array([[float(not p.seen[t].cut[0]), float(not p.seen[t].cut[1])] for t in ts])
        truth = np.stack([[o.centre(k, t) for t in ts] for k in range(len(o.objects))])
        k = int(np.argmin(np.median(np.linalg.norm(p.at(torch.as_tensor(ts)).numpy()[None] - truth, axis=2), 1)))
        for t0, t1 in P.rest_windows(ts, proj, px, w, settings.rest_px, settings.rest_frames):
            sel = (ts >= t0) & (ts <= t1)
            print(f"{d.name} {o.objects[k].name}: window {t0:.2f}-{t1:.2f} ({sel.sum()} frames): "
                  f"the object moved {np.ptp(truth[k][sel], 0).max():.3f} m")
