"""Who draws the moving objects in a finished run's own training views: thermal error (K) on the
moving-object pixels of every training thermal view (the dataset's masks), rendered as trained,
with every body Gaussian made transparent, and with every static Gaussian made transparent; and the
same for the held-out (test) views. If the objects stay right without the bodies, something other
than the bodies draws them in the training views.

    python bench/results/who-draws/who_draws.py RUN DATA      # development seeds only
"""
import sys
from pathlib import Path

import torch

from recon.data import load_dataset
from recon.eval.evaluate import moving_masks
from recon.render import render_frame
from recon.scene import Scene
from recon.train.trainer import Trainer

run, data = Path(sys.argv[1]), Path(sys.argv[2])
torch.set_num_threads(2)
scene = Scene(load_dataset(data))
trainer = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda _: None)
model, g = trainer.model, trainer.model.gaussians
body = g["motion_basis"] > 0
saved = g["opacity_thermal"].detach().clone()


@torch.no_grad()
def moving_mae(views, hide: torch.Tensor | None) -> float:
    g["opacity_thermal"].data.copy_(saved)
    if hide is not None:
        g["opacity_thermal"].data[hide] = -30.0
    masks = moving_masks(scene.dataset, [v.frame for v in views])
    errs = []
    for v in views:
        m = masks[v.frame.file_path]
        if m is None or not m.any():
            continue
        target, valid = scene.target(v)
        keep = torch.from_numpy(m) & valid
        pred = render_frame(model, "thermal", v.time, v.camera)[..., 0]
        errs.append((scene.kelvin(pred) - scene.kelvin(target)).abs()[keep])
    return float(torch.cat(errs).mean())


for name, views in (("training views", scene.train["thermal"]), ("test views", scene.test["thermal"])):
    print(f"{name}: moving-object thermal MAE as trained {moving_mae(views, None):.1f} K, "
          f"without the bodies' Gaussians {moving_mae(views, body):.1f} K, "
          f"bodies only {moving_mae(views, ~body):.1f} K")
