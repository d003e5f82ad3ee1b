"""Where a path's error comes from, per moving path on development datasets (the simulator's objects
are read): how far its blobs' centroids are from the projected middle of the object it follows
(px), how far the fitted path projects from its blobs and from that middle (px), and its 3D error
(m) over its own frames and over the whole sequence. Blobs on the object with the path still off
in 3D: the error is along the rays (depth). Blobs off the object: merged or biased blobs.

    python bench/results/path-smooth/blob_bias.py DATA... > bench/results/path-smooth/blob_bias.txt

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
for name in sys.argv[1:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    ds = load_dataset(d)
    scene = Scene(ds)
    views = {t: scene.views_at('thermal', t)[0] for t in scene.times if scene.views_at('thermal', t)}
    every = np.array(sorted(views))
    for p in P.tracked_paths(scene, settings).moving:
        ts = np.array(sorted(p.seen))
        truth = np.stack([[o.centre(k, t) for t in ts] for k in range(len(o.objects))])
        est = p.at(torch.as_tensor(ts)).numpy()
        k = int(np.argmin(np.median(np.linalg.norm(est[None] - truth, axis=2), 1)))
        proj = np.stack([P.projection(views[t].camera) for t in ts])
        middle, blob, fit = P.to_pixels(proj, truth[k]), np.stack([p.seen[t].centroid for t in ts]), P.to_pixels(proj, est)
        bias = np.linalg.norm(blob - middle, axis=1)
        whole = np.linalg.norm(p.at(torch.as_tensor(every)).numpy() - np.stack([o.centre(k, t) for t in every]), axis=1)
        # majority mask label under each blob: which objects the track followed
        labels = [int(np.bincount(ds.mask(views[t].frame).ravel()[p.seen[t].pixels]).argmax()) for t in ts]
        names = {int(i): v['name'] for i, v in ds.mask_labels.items()}
        followed = ', '.join(f'{names.get(lab, "background")} {labels.count(lab)}' for lab in dict.fromkeys(labels))
        print(f'{d.name} {o.objects[k].name}: {len(ts)} frames ({followed}); blob to middle {np.median(bias):.2f} px '
              f'(max {bias.max():.2f}); fit to blob {np.median(np.linalg.norm(fit - blob, axis=1)):.2f} px; fit to middle '
              f'{np.median(np.linalg.norm(fit - middle, axis=1)):.2f} px; 3D {np.median(np.linalg.norm(est - truth[k], axis=1)):.3f} m '
              f'on its frames, {np.median(whole):.3f} m over the sequence')
        sys.stdout.flush()
