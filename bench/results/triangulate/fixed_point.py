"""Per body of a finished run: its centre path against the nearest moving object of the simulator,
and where one more smoothest-path solve (recon/train/triangulate.py at 23f028c) would put it.

    GMIN=0 PYTHONPATH=CHECKOUT_AT_23f028c python bench/results/triangulate/fixed_point.py RUN DATA family-inside 40

GMIN: only body members whose gate exceeds it make the centre. OPAC: the opacity that weighs the
centre (default opacity_rgb; opacity_thermal). Development seeds only."""
import os, sys, json, numpy as np, torch
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
from pathlib import Path
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.dtg.motion import apply_motion
from recon.train.triangulate import knot_cameras, in_view, smooth_path, camera_pins_depth
run, data, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
import os; GMIN = float(os.environ.get('GMIN', '0'))
scene = Scene(load_dataset(data))
tr = Trainer.resume(run / 'checkpoints' / 'latest.pt', scene, log=lambda _: None)
o = Oracle(variant, seed)
m, g = tr.model, tr.model.gaussians
motion = m.motion; K = motion.translation.shape[1]
gate = m.dynamic_gate().detach(); w = torch.sigmoid(g[os.environ.get('OPAC', 'opacity_rgb')]).detach() * gate
cams = knot_cameras(scene, 'rgb', K, 0, 1)
times = np.arange(K) / (K - 1)
truth = [np.array([o.pose(k, t).position for t in times]) for k in range(len(o.objects))]
with torch.no_grad():
  for b in range(motion.count):
    sel = ((g['motion_basis'] == b + 1) & (gate > GMIN)).nonzero()[:, 0]
    ws = w[sel]
    if float(ws.sum()) < 1: print(b, 'faint', float(ws.sum())); continue
    c = torch.stack([(apply_motion(g['means'][sel], None, g['motion_basis'][sel], gate[sel], motion, k / (K - 1))[0] * ws[:, None]).sum(0) / ws.sum() for k in range(K)]).numpy()
    d = [np.linalg.norm(c - T, axis=1) for T in truth]
    k = int(np.argmin([np.median(x) for x in d]))
    along = []
    eye = np.zeros((K, 3)); ray = np.zeros((K, 3)); on = np.zeros(K)
    for j in range(K):
        cs = cams.get(j)
        if not cs: along.append(np.nan); continue
        e = cs[0].center.numpy(); r = truth[k][j] - e; r /= np.linalg.norm(r)
        along.append(float((c[j] - truth[k][j]) @ r))
        if in_view(cs[0], torch.tensor(c[j], dtype=torch.float32)):
            eye[j] = e; rr = c[j] - e; ray[j] = rr / np.linalg.norm(rr); on[j] = 1
    along = np.array(along)
    pins = camera_pins_depth(torch.tensor(eye), torch.tensor(c, dtype=torch.float64), torch.tensor(on))
    p = smooth_path(torch.tensor(eye), torch.tensor(ray), torch.tensor(on), torch.tensor(c, dtype=torch.float64), 100.0).numpy()
    dn = ((p - eye) * ray).sum(1); new = eye + dn[:, None] * ray
    dnew = np.linalg.norm(np.where(on[:, None] > 0, new, c) - truth[k], axis=1)
    # lateral residual of rays vs solved path
    lat = np.linalg.norm((p - eye) - dn[:, None] * ray, axis=1)[on > 0]
    print(f'body {b}: {len(sel)} G, mass {float(ws.sum()):.1f}, gate {float((gate[sel]*ws).sum()/ws.sum()):.2f} -> obj {k} ({o.objects[k].shape.__class__.__name__}); '
          f'dist median {np.median(d[k]):.2f} max {d[k].max():.2f}; along-ray median {np.nanmedian(np.abs(along)):.2f}; in view {int(on.sum())}; pins {pins}; '
          f'after one more solve: dist median {np.median(dnew):.2f} max {dnew.max():.2f}; lateral resid median {np.median(lat):.3f} max {lat.max():.3f}')
