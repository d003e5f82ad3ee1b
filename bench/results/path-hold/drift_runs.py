"""Where did training leave the bodies of finished runs? For each `recon run` folder on a family
dataset (the simulator's objects are read), each body's centre (pivot + translation) against the
object it follows: at its triangulated path (the anchors) and as trained, median distance over the
thermal training instants and its median part along the thermal camera's ray, beside the object's
held-out thermal MAE from the run's metrics.json. Development datasets only:

    python bench/results/path-hold/drift_runs.py RUN... > drift.txt
"""
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench')); sys.path.insert(0, str(ROOT / 'bench/results/path-anchor'))
from oracle import Oracle  # noqa: E402
from probe_drift import centres, grade  # noqa: E402
from train_step import resume_held  # noqa: E402
from recon.dtg.time_embedding import lerp_rows  # noqa: E402

torch.set_grad_enabled(False)
for run in map(Path, sys.argv[1:]):
    trainer, _ = resume_held(run)
    motion, scene = trainer.model.motion, trainer.scene
    meta = json.loads((scene.dataset.root / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
    truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])
    eyes = np.stack([scene.views_at('thermal', float(t))[0].camera.center.double().numpy() for t in times])
    print(f'{run.parent.name} {run.name}')
    end = centres(trainer.model, times)
    if end is None:
        print('   no bodies')
        continue
    start = np.stack([(motion.pivots + lerp_rows(motion.anchors, float(t), dim=1)).numpy() for t in times], 1)
    objects = json.loads((run / 'metrics.json').read_text())['metrics']['objects']['thermal']
    names = [ob.name for ob in o.objects]
    for a, b in zip(grade(start, truth, eyes, names), grade(end, truth, eyes, names)):
        mae = objects.get(a[0], {}).get('mae_k', float('nan'))
        print(f'   {a[0]:14s} path {a[1]:.3f} (along {a[3]:.3f}) -> trained {b[1]:.3f} (along {b[3]:.3f}) m; '
              f'held-out MAE {mae:.1f} K')
    sys.stdout.flush()
