"""On a finished dtg run: slide each body's knots along their thermal training rays to the depth of
the smoothest path through the rays via hot-blob centroids of the thermal training frames (data
only: a blob is a connected region >= the frame's median + 10 K, off the border, >= 4 px; a body
takes the nearest blob within R px of its hot centre: thermal opacity x (temperature - median -
10 K) weighted, in the thermal render at each knot). Prints each body's nearest-blob distance per
knot, its distance to the simulator's object before -> after (development seeds only), and the
held-out grade before -> after (NOSCORE=1 skips grading).

    python bench/results/blob-rays/posthoc_blob.py RUN DATA family-inside 40 12 >> posthoc.txt"""
import sys, json, numpy as np, torch, cv2
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'bench')); sys.path.insert(0, str(Path(__file__).parent))
from pathlib import Path
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.run import evaluate_model
from recon.dtg.motion import apply_motion
from results_solve import solve

run, data, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
R = float(sys.argv[5]) if len(sys.argv) > 5 else 12.0
LAM = 100.0
torch.set_num_threads(2)
scene = Scene(load_dataset(data))
load = lambda: Trainer.resume(run / 'checkpoints' / 'latest.pt', scene, log=lambda _: None)
def score(tr):
    m = evaluate_model(tr, every=2); r = m['regions']['thermal']
    return f"th MAE {m['thermal']['mae_k']:.2f} mov {r['moving']['mae_k']:.1f} static {r['static']['mae_k']:.2f} rgb {m['rgb']['psnr']:.2f}"

def blobs(view):
    u, valid = scene.target(view); k = scene.kelvin(u).numpy(); v = valid.numpy()
    hot = (k >= np.median(k[v]) + 10) & v
    n, lab, st, cent = cv2.connectedComponentsWithStats(hot.astype(np.uint8), connectivity=8)
    H, W = hot.shape
    return [cent[i] for i in range(1, n) if st[i][4] >= 4 and not (st[i][0] == 0 or st[i][1] == 0 or st[i][0] + st[i][2] >= W or st[i][1] + st[i][3] >= H)]

def pix(cam, p):
    pc = cam.viewmat[:3, :3] @ p + cam.viewmat[:3, 3]
    return np.array([float(cam.fx * pc[0] / pc[2] + cam.cx), float(cam.fy * pc[1] / pc[2] + cam.cy)]), float(pc[2])
def ray(cam, uv):
    d = torch.tensor([(uv[0] - cam.cx) / cam.fx, (uv[1] - cam.cy) / cam.fy, 1.0], dtype=torch.float32)
    d = cam.viewmat[:3, :3].T @ d
    return (d / d.norm()).numpy()

tr = load()
g = tr.model.gaussians; motion = tr.model.motion; K = motion.translation.shape[1]
gate = tr.model.dynamic_gate().detach()
w_all = torch.sigmoid(g['opacity_thermal']).detach() * gate
knot_view = {}
for t in scene.times:
    vs = scene.views_at('thermal', t)
    if vs: knot_view[round(t * (K - 1))] = vs[0]
knot_blobs = {k: blobs(v) for k, v in knot_view.items()}
from recon.render import inference_masks
masks = inference_masks(tr.model)
with torch.no_grad():
    INP = [tr.model.render_inputs('thermal', k / (K - 1), mask=None if masks is None else masks['thermal']) for k in range(K)]
THR = {}
for k in range(K):
    v = knot_view.get(k)
    if v is None: THR[k] = 1.0; continue
    u, valid = scene.target(v); THR[k] = float(u[valid].median()) + 10 / (scene.k_max - scene.k_min)
o = Oracle(variant, seed); times = np.arange(K) / (K - 1)
truth = [np.array([o.pose(k, t).position for t in times]) for k in range(len(o.objects))]
import os
NOSCORE = os.environ.get('NOSCORE')
if not NOSCORE: print('as trained ', score(tr), flush=True)
moves = []; DBG = []
with torch.no_grad():
    for b in range(motion.count):
        sel = (g['motion_basis'] == b + 1).nonzero()[:, 0]
        ws = w_all[sel]
        if float(ws.sum()) < 1: continue
        mean_gate = float((gate[sel] * ws).sum() / ws.sum())
        xs = []
        for k in range(K):
            inp = INP[k]; wk = inp['opacities'][sel] * (inp['features'][sel, 0, 0] - THR[k]).clamp_min(0)
            if float(wk.sum()) < 1e-3: wk = ws
            xs.append((inp['means'][sel] * wk[:, None]).sum(0) / wk.sum())
        x = torch.stack(xs).numpy()
        C = np.zeros((K, 3)); D = np.zeros((K, 3)); Wt = np.zeros(K); own = np.zeros((K, 3)); has = np.zeros(K, bool)
        for k in range(K):
            v = knot_view.get(k)
            if v is None: continue
            cam = v.camera; c = cam.center.numpy(); uv, z = pix(cam, torch.from_numpy(x[k]).float())
            C[k] = c; has[k] = True
            own[k] = (x[k] - c) / np.linalg.norm(x[k] - c)
            bl = knot_blobs[k]
            if bl: DBG.append(round(float(min(np.linalg.norm(q - uv) for q in bl)), 1))
            if z > 0 and bl:
                best = min(bl, key=lambda q: np.linalg.norm(q - uv))
                if np.linalg.norm(best - uv) < R:
                    D[k] = ray(cam, best); Wt[k] = 1
        for k in range(K):
            if Wt[k] == 0 and has[k]: D[k] = own[k]
        print('nearest blob px', DBG); DBG.clear()
        if Wt.sum() < 6 or not has.all():
            print(f'body {b}: {int(Wt.sum())} blob rays, skipped'); continue
        acc = lambda y: np.sum((y[2:] - 2 * y[1:-1] + y[:-2]) ** 2)
        p = solve(C, D, Wt, LAM)
        d_old = np.einsum('ki,ki->k', x - C, own)
        d_new = np.einsum('ki,ki->k', p - C, own)   # depth of the solved point along the body's own ray
        d_new = np.clip(d_new, d_old / 2, d_old * 2)
        target = C + d_new[:, None] * own
        near = min(range(len(truth)), key=lambda j: np.median(np.linalg.norm(x - truth[j], axis=1)))
        before = np.median(np.linalg.norm(x - truth[near], axis=1)); after = np.median(np.linalg.norm(target - truth[near], axis=1))
        print(f'body {b}: mass {float(ws.sum()):.1f} gate {mean_gate:.2f} rays {int(Wt.sum())} cam/body acc {acc(C)/max(acc(x),1e-12):.1f} -> obj {near}: dist {before:.3f} -> {after:.3f} m, depth change median {np.median(np.abs(d_new-d_old)):.3f}', flush=True)
        moves.append((b, sel, torch.from_numpy((target - x) / mean_gate).float(), float(np.median(d_new / d_old))))
    for b, sel, dt, scale in moves:
        motion.translation.data[b] += dt
        members = sel[gate[sel] > 0.5]
        if len(members) and abs(scale - 1) > 1e-3:
            wm = w_all[members]; c0 = (g['means'][members] * wm[:, None]).sum(0) / wm.sum()
            g['means'].data[members] = c0 + scale * (g['means'][members] - c0)
            g['log_scales'].data[members] += float(np.log(scale))
if not NOSCORE: print('post-hoc   ', score(tr), flush=True)
