"""Can the thermal frames alone tell a moving hot object's pixels from everything static? At the
instant dtg's bodies are seen (t_c), take the thermal training frame's hot pixels (10 K above its
median, off the border), chain DIS optical flow (OpenCV, preset medium) from each through every
thermal training frame forward and backward (a track ends where the backward flow misses by more
than 1 px), and call a pixel moving where no static point at any depth on its ray (0.3-6 m, 40
depths) follows its track within 8 px (median over the steps). Graded by the simulator's
per-frame moving-object masks at t_c (dilated by 1 px): precision (moving pixels on a moving
object) and recall (hot pixels on a moving object that are called moving). Development datasets:

    python bench/results/hot-blobs/probe_blobs.py DATA... > bench/results/hot-blobs/probe_blobs.txt"""
import sys
from pathlib import Path
import cv2
import numpy as np
import torch
ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from recon.config import make_config  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.eval.evaluate import moving_masks  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train.initial import initial_model  # noqa: E402

torch.set_grad_enabled(False)
dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)


def grey(scene, view):
    x = scene.target(view)[0].numpy()
    lo, hi = np.percentile(x, 1), np.percentile(x, 99.5)
    return (np.clip((x - lo) / max(hi - lo, 1e-6), 0, 1) * 255).astype(np.uint8)


def sample(f, p):
    h, w = f.shape[:2]
    x, y = np.clip(p[:, 0], 0, w - 1.001), np.clip(p[:, 1], 0, h - 1.001)
    x0, y0 = x.astype(int), y.astype(int)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    return (f[y0, x0] * (1 - ax) * (1 - ay) + f[y0, x0 + 1] * ax * (1 - ay)
            + f[y0 + 1, x0] * (1 - ax) * ay + f[y0 + 1, x0 + 1] * ax * ay)


def tracks(frames, start, k0):
    t, m = len(frames), len(start)
    h, w = frames[0].shape
    uv = np.zeros((t, m, 2)); valid = np.zeros((t, m), bool)
    uv[k0], valid[k0] = start, True
    for step in (1, -1):
        p, alive, i = start.copy(), np.ones(m, bool), k0
        while alive.any() and 0 <= i + step < t:
            j = i + step
            q = p + sample(dis.calc(frames[i], frames[j], None), p)
            back = q + sample(dis.calc(frames[j], frames[i], None), q)
            alive &= (np.linalg.norm(back - p, axis=1) <= 1.0) & (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
            uv[j], valid[j] = q, alive
            p, i = q, j
    return uv, valid


def pixels(cam, xyz):
    pc = xyz @ cam.viewmat[:3, :3].numpy().T + cam.viewmat[:3, 3].numpy()
    z = np.maximum(pc[:, 2], 1e-6)
    return np.stack([cam.fx * pc[:, 0] / z + cam.cx, cam.fy * pc[:, 1] / z + cam.cy], 1), pc[:, 2]


for name in sys.argv[1:]:
    scene = Scene(load_dataset(name))
    cfg = make_config('dtg')
    initial_model(cfg, scene, torch.Generator().manual_seed(cfg.seed), lambda *a: None)
    times = [t for t in scene.times if scene.views_at('thermal', t)]
    views = [scene.views_at('thermal', t)[0] for t in times]
    k0 = int(np.argmin(np.abs(np.asarray(times) - cfg.curriculum.center)))
    frame, ok = scene.target(views[k0])
    kelvin = scene.kelvin(frame)
    hot = (kelvin >= kelvin[ok].median() + 10.0) & ok
    hot[:2], hot[-2:], hot[:, :2], hot[:, -2:] = False, False, False, False
    v, u = np.nonzero(hot.numpy())
    start = np.stack([u, v], 1) + 0.5
    mask = moving_masks(scene.dataset, [views[k0].frame])[views[k0].frame.file_path]
    mask = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if len(start) == 0:
        print(f'{Path(name).name:22s} t_c {times[k0]:.2f} no hot pixels'); continue
    uv, valid = tracks([grey(scene, x) for x in views], start, k0)
    cam0 = views[k0].camera
    rot, tr = cam0.viewmat[:3, :3].numpy(), cam0.viewmat[:3, 3].numpy()
    rays = np.stack([(start[:, 0] - cam0.cx) / cam0.fx, (start[:, 1] - cam0.cy) / cam0.fy, np.ones(len(start))], 1)
    best = np.full(len(start), np.inf)
    for depth in np.geomspace(0.3, 6.0, 40):
        world = (rays * depth - tr) @ rot
        err = np.full((len(times), len(start)), np.nan)
        for k, x in enumerate(views):
            p, z = pixels(x.camera, world)
            err[k] = np.where(valid[k] & (z > 1e-3), np.linalg.norm(uv[k] - p, axis=1), np.nan)
        best = np.minimum(best, np.nan_to_num(np.nanmedian(err, 0), nan=np.inf))
    moving = best > 8.0
    on = mask[v, u]
    prec = (moving & on).sum() / max(moving.sum(), 1)
    rec = (moving & on).sum() / max(on.sum(), 1)
    print(f'{Path(name).name:22s} t_c {times[k0]:.2f} hot {len(start):4d} on moving objects {on.sum():4d} '
          f'called moving {moving.sum():4d} precision {prec:.2f} recall {rec:.2f} '
          f'tracked steps median {np.median(valid.sum(0)):.0f} of {len(times)}', flush=True)
