"""RGB PSNR of a run per frame (every 5th view): as rendered, with a per-channel gain fitted to the
frame, and with the render blurred 3x3 (medians; the last three numbers: the gains).

    python bench/results/mip/gain.py DATA RUN
"""
import sys
from pathlib import Path
import cv2
import numpy as np, recon, torch
from recon.data import load_dataset
from recon.render import load_run, render_frame
from recon.scene import Scene
data, run = Path(sys.argv[1]), Path(sys.argv[2])
model, _ = load_run(run); scene = Scene(load_dataset(data))
for split, views in (("train", scene.train["rgb"][::5]), ("test", scene.test["rgb"][::5])):
    out = []
    for v in views:
        gt, _ = scene.target(v)
        with torch.no_grad(): pr = render_frame(model, "rgb", v.time, v.camera)
        g = gt.reshape(-1, 3).numpy(); p = pr.reshape(-1, 3).numpy()
        gain = (g * p).sum(0) / (p * p).sum(0)
        mse0 = ((g - p) ** 2).mean(); mse1 = ((g - p * gain) ** 2).mean()
        # blur: compare against a 3x3 box of the render
        pb = cv2.blur(pr.numpy(), (3, 3)); mse2 = ((gt.numpy() - pb) ** 2).mean()
        out.append((-10*np.log10(mse0), -10*np.log10(mse1), -10*np.log10(mse2), *gain))
    o = np.array(out); print(split, "psnr / with per-channel gain / render blurred 3x3, gains:", np.round(np.median(o, 0), 3))
