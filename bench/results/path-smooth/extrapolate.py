"""Beyond the frames a path was fitted to, is its straight continuation (what the fit's smoothness
gives) nearer the object than holding it at its last measured place? Per moving path on
development datasets (the simulator's objects are read), the 3D error at the instants outside its
measured span, both ways.

    python bench/results/path-smooth/extrapolate.py DATA... > bench/results/path-smooth/extrapolate.txt

PATHS='{...}' (JSON) overrides PathConfig fields."""
import json
import os
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
settings = P.PathConfig(**json.loads(os.environ.get('PATHS', '{}')))
moved, held = [], []
for name in sys.argv[1:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    scene = Scene(load_dataset(d))
    times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
    truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])
    for p in P.tracked_paths(scene, settings).moving:
        est = p.at(torch.as_tensor(times)).numpy()
        dist = np.linalg.norm(est[None] - truth, axis=2)
        k = int(np.argmin(np.median(dist, 1)))
        lo, hi = min(p.seen), max(p.seen)
        out = (times < lo) | (times > hi)
        if np.median(dist[k]) > 0.3 or not out.any():
            continue
        at_end = p.at(torch.as_tensor(np.clip(times, lo, hi))).numpy()
        e1, e2 = np.linalg.norm(est - truth[k], axis=1)[out], np.linalg.norm(at_end - truth[k], axis=1)[out]
        moved += list(e1)
        held += list(e2)
        print(f'{d.name} {o.objects[k].name} span {lo:.2f}-{hi:.2f}, {out.sum()} instants outside: continued median '
              f'{np.median(e1):.3f} max {e1.max():.3f} m | held {np.median(e2):.3f} max {e2.max():.3f} m')
print(f'all instants outside a span: continued median {np.median(moved):.3f} p90 {np.percentile(moved, 90):.3f} m | '
      f'held median {np.median(held):.3f} p90 {np.percentile(held, 90):.3f} m')
