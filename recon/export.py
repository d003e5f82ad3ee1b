"""Export a trained model: the canonical Gaussians as a 3DGS PLY (plus thermal, second opacity,
routing role and embeddings as extra properties) and the deformation weights."""
from __future__ import annotations

from pathlib import Path

import torch

from recon.dtg import routing
from recon.dtg.model import DTGModel
from recon.splat.ply import write_gaussians_ply


def model_bytes(model: DTGModel) -> int:
    """Bytes of every learned tensor (float32): what the model costs to keep or ship."""
    return sum(t.numel() * t.element_size() for t in model.state_dict().values())


@torch.no_grad()
def export_ply(model: DTGModel, path: Path) -> None:
    """Standard 3DGS layout for the canonical (time-independent) model. With RGB, f_dc/f_rest and
    opacity are the RGB ones; a thermal-only model writes its temperature as grey so any 3DGS
    viewer shows something."""
    g = {k: v.detach() for k, v in model.gaussians.items()}
    n = g["means"].shape[0]
    main = "rgb" if "rgb" in model.cfg.modalities else "thermal"
    sh = g[f"features_{main}"]
    if f"features_{main}_rest" in g:
        sh = torch.cat([sh, g[f"features_{main}_rest"]], dim=1)
    if sh.shape[2] == 1:
        sh = sh.repeat(1, 1, 3)
    extra: dict[str, torch.Tensor] = {}
    if "thermal" in model.cfg.modalities and main != "thermal":
        extra["thermal_dc"] = g["features_thermal"].reshape(n, -1)
        if "features_thermal_rest" in g:
            extra["thermal_rest"] = g["features_thermal_rest"].reshape(n, -1)
        extra["opacity_thermal"] = g["opacity_thermal"]
    if "route_logits" in g:
        extra["role"] = routing.hard_roles(g["route_logits"]).float()
    for key in g:
        if key.startswith("embedding"):
            extra[key] = g[key]
    write_gaussians_ply(path, g["means"], g["quats"], g["log_scales"], g[f"opacity_{main}"], sh,
                        extra={k: v.cpu().numpy() for k, v in extra.items()})


def export_deformation(model: DTGModel, path: Path) -> None:
    """Deformation networks, time embedding and backgrounds (everything not per-Gaussian)."""
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("gaussians.")}
    torch.save({"state_dict": state, "n_times": model.n_times}, path)
