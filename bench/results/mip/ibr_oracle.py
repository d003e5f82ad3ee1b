"""What perfect geometry would give: each held-out RGB pixel's true surface point (simulator depth)
is looked up, bilinearly, in the training view at the same time step that sees it with true depth
agreeing within 2 % (the training rig's view of that instant; a Lambertian scene, so its colour is
the same from any direction). RGB PSNR of that warp and of a run's render, on those seen static pixels.

    python bench/results/mip/ibr_oracle.py DATA RUN VARIANT SEED
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
by_time = {v.time: v for v in scene.train["rgb"]}
se_warp = se_model = count = 0.0
for v in scene.test["rgb"]:
    f = v.frame
    tv = by_time.get(v.time)
    if tv is None:
        continue
    tf = tv.frame
    c2w = world.rig_pose(1, f.timestamp_s)[0]
    d = world.render_depth(c2w, f.fx, f.fy, f.cx, f.cy, f.width, f.height, f.timestamp_s)
    c2w0 = world.rig_pose(0, tf.timestamp_s)[0]
    d0 = world.render_depth(c2w0, tf.fx, tf.fy, tf.cx, tf.cy, tf.width, tf.height, tf.timestamp_s)
    h, w = d.shape
    u, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pts = np.stack([(u - f.cx) / f.fx * d, (vv - f.cy) / f.fy * d, d, np.ones_like(d)], -1).reshape(-1, 4) @ c2w.T
    p = pts @ np.linalg.inv(c2w0).T
    z = p[:, 2]
    x = p[:, 0] / np.maximum(z, 1e-6) * tf.fx + tf.cx
    y = p[:, 1] / np.maximum(z, 1e-6) * tf.fy + tf.cy
    inside = (z > 0.05) & (x >= 1) & (x < tf.width - 1) & (y >= 1) & (y < tf.height - 1)
    xi, yi = np.clip(x.astype(int), 0, tf.width - 1), np.clip(y.astype(int), 0, tf.height - 1)
    seen = (inside & (np.abs(d0[yi, xi] - z) < 0.02 * z)).reshape(h, w) & np.isfinite(d) & (d < 50)
    src, _ = scene.target(tv)
    warp = cv2.remap(src.numpy(), (x - 0.5).reshape(h, w).astype(np.float32), (y - 0.5).reshape(h, w).astype(np.float32),
                     cv2.INTER_LINEAR)
    gt, _ = scene.target(v)
    with torch.no_grad():
        pr = render_frame(model, "rgb", v.time, v.camera)
    m = cv2.imread(str(data / "masks/rgb" / Path(f.file_path).name), cv2.IMREAD_UNCHANGED)
    k = seen & ((m == 0) if m is not None else True)
    g = gt.numpy()
    se_warp += float(((warp - g) ** 2).mean(-1)[k].sum())
    se_model += float(((pr.numpy() - g) ** 2).mean(-1)[k].sum())
    count += int(k.sum())
print(f"{run.parent.name}/{run.name}: held-out static pixels the training view of the same instant saw "
      f"({count / (len(scene.test['rgb']) * h * w) * 100:.0f} % of pixels): true-depth warp {-10 * np.log10(se_warp / count):.2f} dB, "
      f"model {-10 * np.log10(se_model / count):.2f} dB")
