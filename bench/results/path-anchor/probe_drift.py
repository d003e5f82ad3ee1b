"""Do the bodies on tracked paths (curriculum.tracked_paths) stay on them while training? Per
dataset, trains `dtg` for SECONDS of wall time (one thread) and grades each body's centre (pivot +
translation) against the simulator's moving object it follows, at the start (the triangulated
path) and at the end: median and largest distance over the thermal training instants, and the
median part along the thermal camera's ray. Development datasets only (the simulator's objects are
read):

    python bench/results/path-anchor/probe_drift.py SECONDS '{}' DATA...
    python bench/results/path-anchor/probe_drift.py SECONDS '{"priors.path_anchor": 100}' DATA...
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle  # noqa: E402
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.trainer import Trainer  # noqa: E402
from table import apply_overrides  # noqa: E402


def centres(model, times):
    """(B, T, 3) the bodies' pivots moved by their translations at times, or None."""
    motion = model.motion
    if motion is None or motion.count == 0:
        return None
    with torch.no_grad():
        return np.stack([(motion.pivots + motion.at(float(t))[1]).numpy() for t in times], 1)


def grade(c, truth, eyes, names):
    """Per body: (object, median distance, largest, median along the ray) against the nearest object."""
    rows = []
    for body in c:
        err = np.linalg.norm(body[None] - truth, axis=2)
        k = int(np.argmin(np.median(err, 1)))
        rays = truth[k] - eyes
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        along = np.abs(np.einsum('ti,ti->t', body - truth[k], rays))
        rows.append((names[k], float(np.median(err[k])), float(err[k].max()), float(np.median(along))))
    return rows


def main():
    seconds, overrides = float(sys.argv[1]), json.loads(sys.argv[2])
    for name in sys.argv[3:]:
        d = Path(name)
        meta = json.loads((d / 'sim_meta.json').read_text())['config']
        o = Oracle(meta['variant'], meta['seed'])
        cfg = make_config('dtg', iterations=10**6, threads=1, log_every=10**9, checkpoint_every=10**9)
        apply_overrides(cfg, overrides)
        scene = Scene(load_dataset(d))
        trainer = Trainer(cfg, scene, log=lambda *a: None)
        times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
        truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])
        eyes = np.stack([scene.views_at('thermal', float(t))[0].camera.center.double().numpy() for t in times])
        start = centres(trainer.model, times)
        t0 = time.time()
        while time.time() - t0 < seconds:
            trainer.step()
        end = centres(trainer.model, times)
        print(f'{d.name} {json.dumps(overrides)} iterations {trainer.iteration} bodies {0 if start is None else len(start)}')
        if start is not None:
            names = [ob.name for ob in o.objects]
            for a, b in zip(grade(start, truth, eyes, names), grade(end, truth, eyes, names)):
                print(f'   {a[0]:14s} start median {a[1]:.3f} max {a[2]:.3f} along {a[3]:.3f} m | '
                      f'end median {b[1]:.3f} max {b[2]:.3f} along {b[3]:.3f} m')
        sys.stdout.flush()


if __name__ == '__main__':
    main()
