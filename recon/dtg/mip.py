"""Mip-Splatting's 3D smoothing filter (Yu et al., CVPR 2024, section 4.1).

A training view samples the world at focal / depth pixels per unit length where a Gaussian sits, so
it cannot see detail finer than that. A Gaussian thinner than the finest sampling any training view
had at its place is free to take any shape the training pixels do not contradict, and from another
viewpoint (a floor seen at a grazing angle, from a new direction) such slivers alias. The filter
adds an isotropic variance scale x (depth / focal)^2 of the view that sampled it most finely to
each Gaussian's covariance, and scales its opacity so that its integral stays what it was:

    s'^2 = s^2 + v,   o' = o sqrt(det S / det S') = o exp(sum log s - sum log s').

Per modality (the thermal camera has its own field of view), a not-learned per-Gaussian tensor
`mip_<modality>` holds v; the trainer sets it from the training cameras (`sampling_variance`).
"""
from __future__ import annotations

import torch

MIP_KEYS = {"rgb": "mip_rgb", "thermal": "mip_thermal"}
NEAR = 0.05          # points nearer than this (scene units) to a camera do not count as sampled by it
FRUSTUM_MARGIN = 0.15  # a point this fraction of the view beyond its edges still counts (as Mip-Splatting)


@torch.no_grad()
def sampling_variance(means: torch.Tensor, cameras, scale: float) -> torch.Tensor:
    """means: (N, 3) world points; cameras: PinholeCameras (viewmat, fx, fy, cx, cy, width, height).
    Returns (N,) scale x (depth / focal)^2 of the camera that samples each point most finely (the
    largest focal / depth among those that see it); a point no camera sees gets the largest value of
    the seen ones (Mip-Splatting's rule), and with none seen at all, zero."""
    rate = torch.zeros(means.shape[0], dtype=torch.float32)
    for cam in cameras:
        p = means.float() @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
        z = p[:, 2]
        zs = z.clamp_min(NEAR)
        x = p[:, 0] / zs * cam.fx + cam.cx
        y = p[:, 1] / zs * cam.fy + cam.cy
        mx, my = FRUSTUM_MARGIN * cam.width, FRUSTUM_MARGIN * cam.height
        seen = (z > NEAR) & (x >= -mx) & (x <= cam.width + mx) & (y >= -my) & (y <= cam.height + my)
        rate = torch.maximum(rate, torch.where(seen, min(cam.fx, cam.fy) / zs, torch.zeros_like(zs)))
    seen = rate > 0
    if not bool(seen.any()):
        return torch.zeros_like(rate)
    rate = torch.where(seen, rate, rate[seen].min())
    return scale / rate.square()


def filtered(log_scales: torch.Tensor, opacities: torch.Tensor,
             variance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """log_scales: (N, 3); opacities: (N,) activated; variance: (N,) added to each axis's variance.
    Returns the filtered (log_scales (N, 3), opacities (N,)); differentiable in both inputs."""
    wider = 0.5 * torch.log(torch.exp(2 * log_scales) + variance[:, None])
    return wider, opacities * torch.exp((log_scales - wider).sum(dim=1))
