"""Does dtg fit the far floor in its own training views? RGB PSNR per image third, static pixels,
over the training rig's views (cam0) and the held-out rig's (cam1) of a run.

    python bench/results/mip/train_vs_test.py DATA RUN
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

data, run = Path(sys.argv[1]), Path(sys.argv[2])
model, _ = load_run(run)
scene = Scene(load_dataset(data))
for split, views in (("train rig", scene.train["rgb"]), ("held-out rig", scene.test["rgb"])):
    tot = {}
    for v in views:
        gt, _ = scene.target(v)
        with torch.no_grad():
            pr = render_frame(model, "rgb", v.time, v.camera)
        se = ((gt - pr) ** 2).mean(-1).numpy()
        h = se.shape[0]
        label = data / "masks/rgb" / Path(v.frame.file_path).name
        m = cv2.imread(str(label), cv2.IMREAD_UNCHANGED)
        mov = (m > 0) if m is not None else np.zeros(se.shape, bool)
        rows = np.arange(h)[:, None]
        parts = {"moving": mov, "static top": ~mov & (rows < h // 3),
                 "static mid": ~mov & (rows >= h // 3) & (rows < 2 * h // 3), "static bottom": ~mov & (rows >= 2 * h // 3)}
        for k, msk in parts.items():
            a = tot.setdefault(k, [0.0, 0])
            a[0] += float(se[msk].sum())
            a[1] += int(msk.sum())
    all_se = sum(s for s, _ in tot.values()); all_n = sum(n for _, n in tot.values())
    print(f"{run.parent.name}/{run.name} {split}: whole {-10 * np.log10(all_se / all_n):.2f} dB; " +
          "; ".join(f"{k} {-10 * np.log10(s / max(n, 1)):.2f} dB ({100 * s / all_se:.0f} % of error)" for k, (s, n) in tot.items()))
