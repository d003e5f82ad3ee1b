"""How well does chained optical flow track a moving object's centre in the training frames?
Per dataset (development seeds: the simulator's objects are read), per moving object: start at the
object's true projected centre at the middle step, chain OpenCV's DIS flow (preset medium) step by
step forward and backward in the thermal and in the RGB training frames (cam0), and stop where the
forward-backward error exceeds FB px or the point leaves the frame. Prints the steps tracked (of
39) and the median / p90 / max distance to the object's true projected centre.

    python bench/results/flow-tracks/flow_probe.py 1.0 DATA... > bench/results/flow-tracks/flow_probe.txt"""
import sys, json
from pathlib import Path
import numpy as np, cv2, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.scene import Scene
from recon.data import load_dataset

def project(cam, p):
    pc = cam.viewmat[:3, :3].numpy() @ p + cam.viewmat[:3, 3].numpy()
    return np.array([cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy]), pc[2]

def img8(scene, view, modality):
    x, valid = scene.target(view)
    x = x.numpy()
    if modality == 'rgb':
        x = x @ np.array([0.299, 0.587, 0.114])
    else:
        lo, hi = np.percentile(x, 1), np.percentile(x, 99.5)
        x = (x - lo) / max(hi - lo, 1e-6)
    return (np.clip(x, 0, 1) * 255).astype(np.uint8)

dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
def flow(a, b):
    return dis.calc(a, b, None)

def sample(f, p):
    h, w = f.shape[:2]
    x, y = np.clip(p[0], 0, w - 1.001), np.clip(p[1], 0, h - 1.001)
    x0, y0 = int(x), int(y); ax, ay = x - x0, y - y0
    return (f[y0, x0] * (1 - ax) * (1 - ay) + f[y0, x0 + 1] * ax * (1 - ay) + f[y0 + 1, x0] * (1 - ax) * ay + f[y0 + 1, x0 + 1] * ax * ay)

fb_max = float(sys.argv[1]); names = sys.argv[2:]
for name in names:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    scene = Scene(load_dataset(d))
    T = len(scene.times); c = T // 2
    for m in ('thermal', 'rgb'):
        views = [scene.views_at(m, t)[0] for t in scene.times]
        ims = [img8(scene, v, m) for v in views]
        H, W = ims[0].shape
        for k in range(len(o.objects)):
            truth = [project(v.camera, o.pose(k, t).position) for v, t in zip(views, scene.times)]
            uv0, z0 = truth[c]
            if z0 <= 0 or not (0 <= uv0[0] < W and 0 <= uv0[1] < H):
                print(d.name, m, k, 'not in view at centre'); continue
            errs, steps = [], 0
            for direction in (1, -1):
                p = uv0.copy(); i = c
                while 0 <= i + direction < T:
                    j = i + direction
                    f = flow(ims[i], ims[j]); b = flow(ims[j], ims[i])
                    q = p + sample(f, p)
                    back = q + sample(b, q)
                    if np.linalg.norm(back - p) > fb_max or not (0 <= q[0] < W and 0 <= q[1] < H):
                        break
                    p, i = q, j; steps += 1
                    uv, z = truth[j]
                    errs.append(np.linalg.norm(p - uv))
            e = np.array(errs) if errs else np.array([np.nan])
            print(f'{d.name} {m:7s} obj{k} {type(o.objects[k].shape).__name__:8s} tracked {steps:2d}/{T-1} err median {np.median(e):5.1f} p90 {np.percentile(e,90):5.1f} max {e.max():5.1f} px', flush=True)
