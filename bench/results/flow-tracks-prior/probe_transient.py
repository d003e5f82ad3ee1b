"""Which initial points become a body's members, graded by the simulator: the candidates (flagged
by changing_points as by dtg's defaults, or by transient_points as body discovery does) that
observed_time matches to its instant t_seen; how many lie on a moving object at t_seen (1.2 cm),
and on one at any of the simulator's 8 recorded instants. Development datasets only:

    python bench/results/flow-tracks-prior/probe_transient.py DATA... > probe_transient.txt"""
import sys, json
from pathlib import Path
import numpy as np, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.config import make_config
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.initial import initial_points
from recon.dtg.points import changing_points, observed_time, transient_points
torch.set_grad_enabled(False)
for name in sys.argv[1:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    cfg = make_config('dtg'); m = cfg.model
    scene = Scene(load_dataset(d))
    pts, rgb = initial_points(cfg, scene, torch.Generator().manual_seed(cfg.seed), log=lambda *a: None)
    p = pts.numpy()
    for label, cand in (('changing', changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction)),
                        ('transient', transient_points(scene, pts, rgb))):
        t_seen, matched = observed_time(scene, pts[cand], rgb[cand])
        idx = np.nonzero(cand.numpy())[0][matched.numpy()]
        on = np.zeros(len(idx), bool)
        for k in range(len(o.objects)):
            on |= o.contains(k, t_seen, p[idx], 0.012)
        anyt = np.zeros(len(idx), bool)
        for k in range(len(o.objects)):
            for t in np.linspace(0, 1, 8):
                anyt |= o.contains(k, t, p[idx], 0.012)
        print(f'{d.name:22s} {label:9s} t_seen {t_seen:.3f} candidates {len(idx):4d} on an object at t_seen {on.sum():3d} on one at some instant {anyt.sum():3d}')
