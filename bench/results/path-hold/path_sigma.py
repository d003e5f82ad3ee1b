"""How well does a tracked path's own covariance (recon/train/paths.py knot_covariance) say how far
it is from its object? Per development dataset, each moving path found: its median distance from
the simulator's object it is nearest to, beside the median over its frames of the predicted
standard deviation along the thermal camera's ray:

    python bench/results/path-hold/path_sigma.py DATA... > bench/results/path-hold/sigma-dev.txt
"""
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train import paths as P
torch.set_grad_enabled(False)

def sigma_along(path, cameras) -> float:
    """Median over the path's fitted frames of its predicted standard deviation (m) along the ray."""
    times = np.array(sorted(path.seen))
    cov = path.covariance_at(times)                                               # (T, 3, 3)
    eyes = np.stack([cameras[t].center.double().numpy() for t in times])
    rays = path.at(torch.as_tensor(times)).double().numpy() - eyes
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return float(np.median(np.sqrt(np.einsum("ti,tij,tj->t", rays, cov, rays))))


settings = P.PathConfig(**json.loads(os.environ.get('PATHS', '{}')))
for name in sys.argv[1:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    scene = Scene(load_dataset(d))
    views = [(t, scene.views_at('thermal', t)[0]) for t in scene.times if scene.views_at('thermal', t)]
    cameras = {t: v.camera for t, v in views}
    found = P.tracked_paths(scene, settings).moving
    times = np.array([t for t, _ in views])
    truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])
    for p in found:
        err = np.linalg.norm(p.at(torch.as_tensor(times)).numpy()[None] - truth, axis=2)
        k = int(np.argmin(np.median(err, 1)))
        print(f'{d.name:20s} {o.objects[k].name:14s} err {np.median(err[k]):.3f} m  sigma_along {sigma_along(p, cameras):.3f} m  reproj {p.reprojection:.2f} frames {p.frames}')
    sys.stdout.flush()
