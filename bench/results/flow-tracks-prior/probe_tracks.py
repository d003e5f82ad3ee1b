"""Grade the flow tracks of recon/train/tracks.py (at edfc9f0; removed after) in 2D against the simulator's objects:
a track starting within an object's projected disc at k0 should move as the object's centre does.
Per body: its tracks, how many start on a moving object, the steps tracked, and the median / p90
error of a track's displacement against its object's centre's. Development datasets only (the
simulator's objects are read):

    git checkout edfc9f0 && python bench/results/flow-tracks-prior/probe_tracks.py DATA... > probe_tracks.txt"""
import sys, json
from pathlib import Path
import numpy as np, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.config import make_config
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.train.tracks import project
torch.set_grad_enabled(False)
for name in sys.argv[1:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    cfg = make_config('dtg', iterations=3000, threads=2)
    cfg.priors.flow_tracks = 0.01
    tr = Trainer(cfg, Scene(load_dataset(d)), log=lambda m: print('   ', m) if 'flow' in m else None)
    T = tr.tracks
    if T is None:
        print(d.name, 'no tracks'); continue
    k0 = T.step_of(cfg.curriculum.center)
    def centre_uv(k, s):
        c = torch.tensor(o.pose(k, T.times[s]).position, dtype=torch.float32)[None]
        uv, z = project(T.viewmats[s], T.intrinsics[s], c)
        r = float(T.intrinsics[s, 0]) * o.objects[k].size / float(z[0])
        return uv[0], r, float(z[0])
    owner = np.full(len(T.basis), -1)
    for k in range(len(o.objects)):
        c, r, z = centre_uv(k, k0)
        if z <= 0: continue
        inside = (T.uv[k0] - c).norm(dim=1) <= r + 3
        owner[inside.numpy() & (owner < 0)] = k
    print(d.name, f't_c={T.times[k0]:.3f}', 'tracked', len(owner), 'on objects', int((owner >= 0).sum()))
    for b in sorted(set(T.basis.tolist())):
        sel = T.basis.numpy() == b
        errs = []
        for i in np.nonzero(sel & (owner >= 0))[0]:
            k = owner[i]; c0, _, _ = centre_uv(k, k0)
            for s in range(len(T.times)):
                if T.valid[s, i]:
                    cs, _, z = centre_uv(k, s)
                    errs.append(float(((T.uv[s, i] - T.uv[k0, i]) - (cs - c0)).norm()))
        e = np.array(errs) if errs else np.array([np.nan])
        print(f'   body {b}: {sel.sum()} tracks, {(owner[sel] >= 0).sum()} on object(s) {sorted(set(owner[sel].tolist()))}, '
              f'steps {int(T.valid[:, torch.tensor(sel)].any(1).sum())}, displacement err median {np.median(e):.1f} p90 {np.percentile(e, 90):.1f} px')
