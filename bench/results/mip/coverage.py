"""Which held-out pixels did the training rig ever see? Each held-out RGB pixel's true surface point
(the simulator's depth) is projected into every training RGB view at its own time; it counts as
seen when it lands inside one and that view's true depth there agrees within 2 %. RGB PSNR of a
run on seen and unseen static pixels, per image third.

    python bench/results/mip/coverage.py DATA RUN VARIANT SEED
"""
import sys
from pathlib import Path

import cv2
import numpy as np

import recon  # noqa: F401
import torch

from recon.data import load_dataset
from recon.render import load_run, render_frame
from recon.scene import Scene
from rig.sim import make_world

data, run, variant, seed = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
model, _ = load_run(run)
scene = Scene(load_dataset(data))
world = make_world(variant, seed)


def true_depth(rig, f):
    c2w = world.rig_pose(rig, f.timestamp_s)[0]
    return c2w, world.render_depth(c2w, f.fx, f.fy, f.cx, f.cy, f.width, f.height, f.timestamp_s)


train = []
for v in scene.train["rgb"]:
    c2w, d = true_depth(0, v.frame)
    train.append((np.linalg.inv(c2w), v.frame, d))
acc = {}
for v in scene.test["rgb"]:
    f = v.frame
    c2w, d = true_depth(1, f)
    h, w = d.shape
    u, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    cam = np.stack([(u - f.cx) / f.fx * d, (vv - f.cy) / f.fy * d, d, np.ones_like(d)], -1)
    pts = cam.reshape(-1, 4) @ c2w.T
    seen = np.zeros(h * w, bool)
    for w2c, tf, td in train:
        p = pts @ w2c.T
        z = p[:, 2]
        x = p[:, 0] / np.maximum(z, 1e-6) * tf.fx + tf.cx
        y = p[:, 1] / np.maximum(z, 1e-6) * tf.fy + tf.cy
        inside = (z > 0.05) & (x >= 0) & (x < tf.width) & (y >= 0) & (y < tf.height)
        xi = np.clip(x.astype(int), 0, tf.width - 1)
        yi = np.clip(y.astype(int), 0, tf.height - 1)
        seen |= inside & (np.abs(td[yi, xi] - z) < 0.02 * z)
    seen = seen.reshape(h, w) & np.isfinite(d) & (d < 50)
    gt, _ = scene.target(v)
    with torch.no_grad():
        pr = render_frame(model, "rgb", v.time, v.camera)
    se = ((gt - pr) ** 2).mean(-1).numpy()
    m = cv2.imread(str(data / "masks/rgb" / Path(f.file_path).name), cv2.IMREAD_UNCHANGED)
    static = (m == 0) if m is not None else np.ones((h, w), bool)
    rows = np.arange(h)[:, None]
    for third, sel in (("top", rows < h // 3), ("mid", (rows >= h // 3) & (rows < 2 * h // 3)), ("bottom", rows >= 2 * h // 3)):
        for name, k in (("seen", static & sel & seen), ("unseen", static & sel & ~seen)):
            a = acc.setdefault((third, name), [0.0, 0])
            a[0] += float(se[k].sum())
            a[1] += int(k.sum())
total_se = sum(s for s, _ in acc.values())
total_n = sum(n for _, n in acc.values())
print(f"{run.parent.name}/{run.name} held-out rig, static pixels: " + "; ".join(
    f"{t} {n}: {100 * c / total_n:.0f} % of pixels, {-10 * np.log10(s / max(c, 1)):.2f} dB, {100 * s / total_se:.0f} % of error"
    for (t, n), (s, c) in acc.items()))
