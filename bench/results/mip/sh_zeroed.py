"""Held-out RGB PSNR of a run as trained and with its degree-1 SH colour zeroed (every 4th view).

    python bench/results/mip/sh_zeroed.py DATA RUN
"""
import sys
from pathlib import Path
import numpy as np, recon, torch
from recon.data import load_dataset
from recon.render import load_run, render_frame
from recon.scene import Scene
data, run = Path(sys.argv[1]), Path(sys.argv[2])
model, _ = load_run(run); scene = Scene(load_dataset(data))
def psnr(views):
    se = n = 0
    for v in views:
        gt, _ = scene.target(v)
        with torch.no_grad(): pr = render_frame(model, "rgb", v.time, v.camera)
        se += float(((gt - pr) ** 2).sum()); n += gt.numel()
    return -10 * np.log10(se / n)
a = (psnr(scene.train["rgb"][::4]), psnr(scene.test["rgb"][::4]))
with torch.no_grad(): model.gaussians["features_rgb_rest"].zero_()
b = (psnr(scene.train["rgb"][::4]), psnr(scene.test["rgb"][::4]))
print(run, "train/test PSNR with SH1:", np.round(a, 2), "rest zeroed:", np.round(b, 2))
