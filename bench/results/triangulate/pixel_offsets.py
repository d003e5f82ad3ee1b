"""Where each body of a finished run is in its own training views: the pixel distance between the
RGB projection of its centre (opacity x gate weighted) and that of the nearest moving object's
centre, per training time step. Development seeds only.

    python bench/results/triangulate/pixel_offsets.py RUN DATA family-inside 40
"""
import sys, numpy as np, torch
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3] / "bench"))
from pathlib import Path
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.dtg.motion import apply_motion
run, data, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
scene = Scene(load_dataset(data))
tr = Trainer.resume(run / 'checkpoints' / 'latest.pt', scene, log=lambda _: None)
o = Oracle(variant, seed); g = tr.model.gaussians; motion = tr.model.motion; K = motion.translation.shape[1]
gate = tr.model.dynamic_gate().detach(); w = torch.sigmoid(g['opacity_rgb']).detach() * gate
def pix(cam, p):
    p = torch.as_tensor(p, dtype=torch.float32); pc = cam.viewmat[:3, :3] @ p + cam.viewmat[:3, 3]
    return np.array([float(cam.fx * pc[0] / pc[2] + cam.cx), float(cam.fy * pc[1] / pc[2] + cam.cy)])
views = {round(v.time * (K - 1)): v.camera for v in scene.train['rgb']}
with torch.no_grad():
  for b in range(motion.count):
    sel = (g['motion_basis'] == b + 1).nonzero()[:, 0]; ws = w[sel]
    if float(ws.sum()) < 1: continue
    errs = []; nearest = None
    for k, cam in sorted(views.items()):
        c = (apply_motion(g['means'][sel], None, g['motion_basis'][sel], gate[sel], motion, k / (K - 1))[0] * ws[:, None]).sum(0) / ws.sum()
        d = [np.linalg.norm(pix(cam, c) - pix(cam, o.pose(j, k / (K - 1)).position)) for j in range(len(o.objects))]
        errs.append(d)
    errs = np.array(errs); j = int(np.argmin(np.median(errs, 0)))
    print(f'body {b} -> obj {j}: training-view pixel distance of centres median {np.median(errs[:, j]):.1f} px, p90 {np.percentile(errs[:, j], 90):.1f}, max {errs[:, j].max():.1f} (fx {views[0].fx:.0f})')
