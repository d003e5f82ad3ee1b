"""Held-out views during training: which views judge a run (for the progress line, and when
held-out error decides when to stop or how many Gaussians to grow), and their PSNR."""
from __future__ import annotations

import torch

from recon.config import TrainConfig
from recon.dtg.model import DTGModel
from recon.eval import psnr
from recon.render import render_frame
from recon.scene import Scene, View


def holdout_views(cfg: TrainConfig, scene: Scene, decides: bool) -> tuple[dict[str, list[View]], set[float]]:
    """-> (views per modality, the time steps held out of training).

    The progress line shows the test view nearest the middle of the sequence. When held-out error
    decides something (`decides`), decisions must not look at test data, so they use every 8th
    training time step instead (offset 4), kept out of training until the schedule's hold ends
    (with the automatic budget alone: for the whole run)."""
    every = cfg.stop.validation_every
    held = set(scene.times[every // 2::every]) if decides else set()
    out = {}
    for m in cfg.model.modalities:
        if held:
            out[m] = [v for v in scene.train[m] if v.time in held]
        else:
            views = scene.test[m] or scene.train[m]
            out[m] = [min(views, key=lambda v: abs(v.time - 0.5))] if views else []
    return out, held


@torch.no_grad()
def holdout_psnr(model: DTGModel, scene: Scene, views: dict[str, list[View]]) -> dict[str, float]:
    """Mean PSNR per modality over `views` (thermal on its valid pixels)."""
    out = {}
    for m, vs in views.items():
        scores = []
        for view in vs:
            pred = render_frame(model, m, view.time, view.camera)
            target, valid = scene.target(view)
            if m == "rgb":
                scores.append(float(psnr(pred.clamp(0, 1), target)))
            else:
                scores.append(float(psnr(pred[..., 0].clamp(0, 1), target, mask=valid)))
        if scores:
            out[m] = sum(scores) / len(scores)
    return out
