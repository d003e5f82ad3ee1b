"""A trained dtg run's bodies against the simulator's moving objects, every time step: the distance of
each body's open, opaque Gaussians' centre from the nearest object's centre, its offset along and
across the training thermal camera's ray, and along the test camera's (positive: behind).

    python bench/results/basis-robust/why/body_path.py RUN DATA VARIANT SEED
"""
import sys, json, numpy as np, torch
from pathlib import Path
ROOT = Path(__file__).resolve().parents[4]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / "bench"))
from recon.render import load_run
from body_truth import body_positions
from oracle import Oracle
run, data, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
model, facts = load_run(run)
tf = json.loads((data / 'transforms.json').read_text())
cams = {c: {round(f['time'], 4): np.asarray(f['transform_matrix'])[:3, 3] for f in tf['frames'] if f['modality'] == 'thermal' and f['camera'] == c} for c in ('cam0', 'cam1')}
orc = Oracle(variant, seed)
print("objects", [(o.name, round(float(o.size), 2)) for o in orc.objects])
g = model.gaussians; basis = g["motion_basis"].long()
gate = model.dynamic_gate(torch.arange(len(basis))).detach(); op = torch.sigmoid(g["opacity_thermal"]).detach()
for b in range(model.motion.count):
    rows = ((basis == b + 1) & (gate > 0.5) & (op > 0.3)).nonzero()[:, 0]
    print(f"body {b+1}: {int((basis==b+1).sum())} members, {len(rows)} open+opaque(thermal)")
    if not len(rows): continue
    w = op[rows].numpy()
    for t in sorted(cams['cam0']):
        p = body_positions(model, rows, t)
        c = (p * w[:, None]).sum(0) / w.sum()
        cs = [orc.centre(k, t) for k in range(len(orc.objects))]
        k = int(np.argmin([np.linalg.norm(c - q) for q in cs])); off = c - cs[k]
        r0 = cs[k] - cams['cam0'][t]; r1 = cs[k] - cams['cam1'][t]
        a0 = off @ r0 / np.linalg.norm(r0); a1 = off @ r1 / np.linalg.norm(r1)
        print(f"  t={t:.3f} obj{k} dist {np.linalg.norm(off):.3f} m  along train ray {a0:+.3f}  across {np.sqrt(max(np.linalg.norm(off)**2-a0**2,0)):.3f}  | test ray {a1:+.3f}  depth train {np.linalg.norm(r0):.2f} test {np.linalg.norm(r1):.2f}")
