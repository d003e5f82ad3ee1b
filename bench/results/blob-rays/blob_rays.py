"""Can the thermal frames alone give a moving object's depth? Rays from each thermal training
camera through the centroid of a hot blob (a connected region >= the frame's median + 10 K, off the
border, >= 4 px), the blob taken per time step as the one nearest the simulator's object (within
12 px: the association is the oracle's), then the smoothest path through them (weight 100, as
exact_rays.py in ../triangulate). Per object: (dataset, object, rays, median blob-to-true-centre
px, median depth error along the ray m, median 3D error m); objects with no hot blob: rays 0.

    python bench/results/blob-rays/blob_rays.py DATA... > bench/results/blob-rays/blob_rays.txt"""
import sys, json
from pathlib import Path
import numpy as np, cv2, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench')); sys.path.insert(0, str(Path(__file__).parent))
from oracle import Oracle
from recon.scene import Scene
from recon.data import load_dataset
from results_solve import solve  # noqa

def blobs(scene, view, hot_k=10.0, min_area=4):
    u, valid = scene.target(view)
    k = scene.kelvin(u).numpy(); v = valid.numpy()
    hot = (k >= np.median(k[v]) + hot_k) & v
    n, lab, stats, cent = cv2.connectedComponentsWithStats(hot.astype(np.uint8), connectivity=8)
    out = []
    H, W = hot.shape
    for i in range(1, n):
        x, y, w, h, a = stats[i]
        if a < min_area:
            continue
        border = x == 0 or y == 0 or x + w >= W or y + h >= H
        out.append((cent[i], a, border))
    return out

def project(cam, p):
    pc = cam.viewmat[:3, :3].numpy() @ p + cam.viewmat[:3, 3].numpy()
    return np.array([cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy]), pc[2]

def ray(cam, uv):
    d = np.array([(uv[0] - cam.cx) / cam.fx, (uv[1] - cam.cy) / cam.fy, 1.0])
    d = cam.viewmat[:3, :3].numpy().T @ d
    return d / np.linalg.norm(d)

rows = []
for name in sys.argv[1:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    scene = Scene(load_dataset(d))
    for k in range(len(o.objects)):
        C, D, W, P = [], [], [], []
        pix = []
        for t in scene.times:
            view = scene.views_at('thermal', t)[0]; cam = view.camera
            pos = o.pose(k, t).position
            uv, z = project(cam, pos)
            c = cam.center.numpy()
            P.append(pos); C.append(c)
            bl = [b for b in blobs(scene, view) if not b[2]]
            best = min(bl, key=lambda b: np.linalg.norm(b[0] - uv)) if bl else None
            if z > 0 and best is not None and np.linalg.norm(best[0] - uv) < 12:
                D.append(ray(cam, best[0])); W.append(1.0); pix.append(np.linalg.norm(best[0] - uv))
            else:
                D.append((pos - c) / np.linalg.norm(pos - c)); W.append(0.0)
        C, D, W, P = map(np.array, (C, D, W, P))
        if W.sum() < 6:
            rows.append((d.name, k, int(W.sum()), None, None, None)); print(rows[-1], o.objects[k].shape, flush=True); continue
        p = solve(C, D, W, 100.0)
        depth_true = np.einsum('ti,ti->t', P - C, D)
        depth = np.einsum('ti,ti->t', p - C, D)
        err = np.abs(depth - depth_true)[W > 0]
        err3 = np.linalg.norm(p - P, axis=1)
        rows.append((d.name, k, int(W.sum()), float(np.median(pix)), float(np.median(err)), float(np.median(err3))))
        print(rows[-1], flush=True)
