"""Each moving path of the datasets given, at its frames after t = 0.45 (where the family-fast objects
have stopped): the one still point those blobs triangulate to (DLT) against the fitted path there,
both graded against the simulator's object centre.

    python bench/results/rest-windows/why_static.py DATA... > bench/results/rest-windows/why.txt
"""
import json, sys
from pathlib import Path
import numpy as np, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train import paths as P
torch.set_grad_enabled(False)
for name in sys.argv[1:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed']); scene = Scene(load_dataset(d))
    found = P.tracked_paths(scene, P.PathConfig()).moving
    for p in found:
        ts = np.array(sorted(t for t in p.seen if t > 0.45))
        if len(ts) < 5: continue
        views = {t: scene.views_at('thermal', t)[0] for t in ts}
        proj = np.stack([P.projection(views[t].camera) for t in ts])
        px = np.stack([p.seen[t].centroid for t in ts])
        rows = P.dlt_rows(proj, px)
        x = np.linalg.svd(rows)[2][-1]; X = x[:3] / x[3]
        truth = np.stack([[o.centre(k, t) for t in ts] for k in range(len(o.objects))])
        k = int(np.argmin(np.linalg.norm(truth.mean(1) - X, axis=1)))
        cams = np.stack([np.linalg.inv(views[t].camera.viewmat.double().numpy())[:3, 3] for t in ts])
        dirs = truth[k] - cams; dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        ang = np.degrees(np.arccos(np.clip(dirs @ dirs.mean(0) / np.linalg.norm(dirs.mean(0)), -1, 1))).max()
        rep = np.linalg.norm(P.to_pixels(proj, X) - px, axis=1)
        truepix = np.linalg.norm(P.to_pixels(proj, truth[k].mean(0)) - px, axis=1)
        pathpos = p.at(torch.as_tensor(ts)).numpy().mean(0)
        print(f"{d.name} {o.objects[k].name}: static frames {len(ts)}, ray spread {ang:.1f} deg; static point err {np.linalg.norm(X - truth[k].mean(0)):.3f} m "
              f"(reproj {np.median(rep):.2f} px); truth centre reproj {np.median(truepix):.2f} px; path err {np.linalg.norm(pathpos - truth[k].mean(0)):.3f}; truth moves {np.ptp(truth[k],0).max():.3f}")
