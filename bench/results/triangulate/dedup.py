"""A finished run's held-out error with bodies made transparent: as trained; keeping per object only
the body the simulator says is nearest ("oracle keep"); dropping the lighter of two bodies whose
centres are within 8 pixels of each other (median over the training views, "mass rule").

    python bench/results/triangulate/dedup.py RUN DATA family-inside 41   # development seeds only
"""
import sys, json, numpy as np, torch
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3] / "bench"))
from pathlib import Path
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.run import evaluate_model
from recon.dtg.motion import apply_motion


def knot_cameras(scene, modality, knots, lo, hi):
    out = {}
    for t in scene.times:
        for view in scene.views_at(modality, t):
            out.setdefault(round(t * (knots - 1)), []).append(view.camera)
    return out
run, data, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
torch.set_num_threads(2)
scene = Scene(load_dataset(data))
def load():
    return Trainer.resume(run / 'checkpoints' / 'latest.pt', scene, log=lambda _: None)
def score(tr):
    m = evaluate_model(tr, every=2)
    r = m['regions']['thermal']
    return f"th MAE {m['thermal']['mae_k']:.2f} mov {r['moving']['mae_k']:.1f} static {r['static']['mae_k']:.2f} rgb {m['rgb']['psnr']:.2f}"
tr = load()
g = tr.model.gaussians; motion = tr.model.motion; K = motion.translation.shape[1]
gate = tr.model.dynamic_gate().detach(); w = torch.sigmoid(g['opacity_rgb']).detach() * gate
cams = knot_cameras(scene, 'rgb', K, 0, 1)
paths, mass = {}, {}
with torch.no_grad():
    for b in range(motion.count):
        sel = (g['motion_basis'] == b + 1).nonzero()[:, 0]
        ws = w[sel]; mass[b] = float(ws.sum())
        if mass[b] < 1: continue
        paths[b] = torch.stack([(apply_motion(g['means'][sel], None, g['motion_basis'][sel], gate[sel], motion, k / (K - 1))[0] * ws[:, None]).sum(0) / ws.sum() for k in range(K)])
def pix(cam, p):
    pc = cam.viewmat[:3, :3] @ p + cam.viewmat[:3, 3]
    return torch.stack([cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy])
o = Oracle(variant, seed); times = np.arange(K) / (K - 1)
truth = [np.array([o.pose(k, t).position for t in times]) for k in range(len(o.objects))]
near = {b: min(range(len(truth)), key=lambda k: np.median(np.linalg.norm(p.numpy() - truth[k], axis=1))) for b, p in paths.items()}
dist = {b: float(np.median(np.linalg.norm(p.numpy() - truth[near[b]], axis=1))) for b, p in paths.items()}
print('bodies', {b: (round(mass[b], 1), near.get(b), round(dist.get(b, -1), 2)) for b in range(motion.count)})
# pixel overlap of body paths
pd = {}
for a in paths:
    for b in paths:
        if a < b:
            d = [float((pix(cs[0], paths[a][k]) - pix(cs[0], paths[b][k])).norm()) for k, cs in cams.items()]
            pd[(a, b)] = np.median(d)
print('median pixel distance of pairs', {k: round(v, 1) for k, v in pd.items()})
print('as trained       ', score(tr))
def drop(tr, bodies):
    with torch.no_grad():
        for b in bodies:
            sel = tr.model.gaussians['motion_basis'] == b + 1
            for key in ('opacity_rgb', 'opacity_thermal'):
                if key in tr.model.gaussians: tr.model.gaussians[key][sel] = -30.0
keep = {}
for b in paths:
    k = near[b]
    if k not in keep or dist[b] < dist[keep[k]]: keep[k] = b
t2 = load(); drop(t2, [b for b in range(motion.count) if b not in keep.values()])
print('oracle keep', sorted(keep.values()), score(t2))
# non-oracle: pairs closer than 8 px median in the training views -> drop the lighter
dropped = set()
for (a, b), d in sorted(pd.items(), key=lambda x: x[1]):
    if d < 8 and a not in dropped and b not in dropped:
        dropped.add(a if mass[a] < mass[b] else b)
t3 = load(); drop(t3, dropped)
print('mass rule drop', sorted(dropped), score(t3))
