"""Path error against the path fit's settings, on development datasets (the simulator's objects are
read). For each settings variant (JSON PathConfig overrides), every dataset's moving paths are
matched to the nearest moving object (median distance over the thermal instants, as
bench/results/tracked-paths/probe_paths.py does) and summarised: objects with a path, strays
(> 0.3 m from every object), and the median / 75th percentile / worst of the per-object median
errors (m); and over every path (strays and second paths too), its 90th-percentile distance over
time from its nearest object (a path that follows one object, then another, is caught here).
Graded at each object's middle (Oracle.centre), not its pose's origin: a can's origin is its base.

    python bench/results/path-smooth/sweep.py VARIANTS.json DATA... > bench/results/path-smooth/sweep.txt

VARIANTS.json: {"name": {PathConfig overrides}, ...}. Each object's error per variant is also
printed, so a variant can be read per dataset."""
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


def graded(scene, oracle, found):
    """{object name: median distance (m)} of the paths nearest each object, and the stray count."""
    times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
    truth = np.stack([[oracle.centre(k, t) for t in times] for k in range(len(oracle.objects))])
    best, strays, worst = {}, 0, []
    for p in found:
        dist = np.linalg.norm(p.at(torch.as_tensor(times)).numpy()[None] - truth, axis=2)   # (O, T)
        err = np.median(dist, 1)
        k = int(np.argmin(err))
        worst.append(float(np.percentile(dist[k], 90)))
        if err[k] > 0.3:
            strays += 1
            continue
        name = oracle.objects[k].name
        best[name] = min(best.get(name, np.inf), float(err[k]))
    return best, strays, worst


variants = json.loads(Path(sys.argv[1]).read_text())
datasets = []
for name in sys.argv[2:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    moving = [ob.name for ob in o.objects]      # Oracle keeps the moving objects only
    datasets.append((d.name, Scene(load_dataset(d)), o, moving))

summary = []
for vname, over in variants.items():
    settings = P.PathConfig(**over)
    errs, strays, objects, per, p90 = [], 0, 0, [], []
    for dname, scene, o, moving in datasets:
        best, s, w = graded(scene, o, P.tracked_paths(scene, settings).moving)
        strays += s
        p90 += w
        objects += len(moving)
        errs += list(best.values())
        per.append(f'{dname}: ' + ', '.join(f'{k} {v:.3f}' for k, v in sorted(best.items())) + (f' +{s} stray' if s else ''))
    e = np.array(errs) if errs else np.array([np.nan])
    line = (f'{vname:24s} found {len(errs)}/{objects}, strays {strays}, error median {np.median(e):.3f} '
            f'p75 {np.percentile(e, 75):.3f} worst {e.max():.3f} m; every path ({len(p90)}): 90th-percentile '
            f'error over time, median {np.median(p90):.3f}, paths above 0.2 m {sum(x > 0.2 for x in p90)}')
    summary.append(line)
    print(line, json.dumps(over)); print('   ' + '\n   '.join(per)); sys.stdout.flush()
print('\n'.join(summary))
