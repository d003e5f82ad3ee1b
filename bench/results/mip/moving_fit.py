"""Thermal MAE on the moving objects' pixels (object masks), training rig against held-out rig: does
a run fit its moving objects where it trained, and lose them elsewhere?

    python bench/results/mip/moving_fit.py DATA RUN
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
dataset = load_dataset(data)
scene = Scene(dataset)
moving = [k for k, v in dataset.mask_labels.items() if v["moving"]]
for split, views in (("train rig", scene.train["thermal"]), ("held-out rig", scene.test["thermal"])):
    err, n = 0.0, 0
    for v in views:
        m = cv2.imread(str(data / "masks/thermal" / Path(v.frame.file_path).name), cv2.IMREAD_UNCHANGED)
        k = np.isin(m, moving)
        if not k.any():
            continue
        target, valid = scene.target(v)
        with torch.no_grad():
            u = render_frame(model, "thermal", v.time, v.camera)[..., 0]
        e = (scene.kelvin(u) - scene.kelvin(target)).abs().numpy()
        k &= valid.numpy() if valid is not None else True
        err += float(e[k].sum())
        n += int(k.sum())
    print(f"{run.parent.name}/{run.name} {split}: moving-object thermal MAE {err / max(n, 1):.2f} K over {n} pixels")
