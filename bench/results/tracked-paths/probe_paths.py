"""How near are the paths recon/train/paths.py finds to the simulator's moving objects? Per dataset,
each path found is matched to the moving object whose centre it is nearest to (median over the
sequence) and graded there: median and largest distance (m) over the thermal training instants;
objects no path found are listed as missed, paths no object explains as stray. Development
datasets (the simulator's objects are read):

    python bench/results/tracked-paths/probe_paths.py DATA... > bench/results/tracked-paths/probe_paths.txt

With --oracle-blobs each object's blob is its mask in the simulator's frames instead (what the
triangulation alone can do). PATHS='{"whole_window": 0}' (JSON) overrides PathConfig fields."""
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


def oracle_paths(scene, ds, settings):
    """Paths fitted to the simulator's own per-object masks as blobs."""
    views = [(t, scene.views_at('thermal', t)[0]) for t in scene.times if scene.views_at('thermal', t)]
    cameras = {t: v.camera for t, v in views}
    out = []
    for label, info in ds.mask_labels.items():
        if not info['moving']:
            continue
        track = []
        for t, v in views:
            m = ds.mask(v.frame) == int(label)
            if m.sum() < 4:
                continue
            ys, xs = np.nonzero(m)
            border = xs.min() == 0 or ys.min() == 0 or xs.max() == m.shape[1] - 1 or ys.max() == m.shape[0] - 1
            track.append(P.Blob(t, np.array([xs.mean(), ys.mean()]) + 0.5, int(m.sum()), 1, bool(border),
                              np.flatnonzero(m), m.shape[1]))
        p = P.fit_track(track, cameras, scene.up().double().numpy(), settings)
        if p is not None:
            out.append(p)
    return out


oracle = sys.argv[1] == '--oracle-blobs'
for name in sys.argv[1 + oracle:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    ds = load_dataset(d)
    scene = Scene(ds)
    settings = P.PathConfig(**json.loads(os.environ.get('PATHS', '{}')))   # e.g. PATHS='{"whole_window": 3}'
    found = oracle_paths(scene, ds, settings) if oracle else P.tracked_paths(scene, settings).moving
    times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
    truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])   # (O, T, 3)
    hit = set()
    rows = []
    for p in found:
        err = np.linalg.norm(p.at(torch.as_tensor(times)).numpy()[None] - truth, axis=2)  # (O, T)
        k = int(np.argmin(np.median(err, 1)))
        med, worst = float(np.median(err[k])), float(err[k].max())
        if med > 0.3:
            rows.append(f'stray (nearest {o.objects[k].name} {med:.2f} m) r {p.radius:.2f} frames {p.frames}')
            continue
        hit.add(k)
        rows.append(f'{o.objects[k].name}: median {med:.3f} max {worst:.3f} m, reprojection {p.reprojection:.2f} px, '
                    f'{p.frames} frames, r {p.radius:.2f} m')
    missed = [o.objects[k].name for k in range(len(o.objects)) if k not in hit]
    print(f'{d.name:20s} paths {len(found)}; missed: {", ".join(missed) or "none"}')
    for r in rows:
        print('   ', r)
    sys.stdout.flush()
