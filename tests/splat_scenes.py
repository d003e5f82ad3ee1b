"""Small random Gaussian scenes and cameras for the rasterizer tests (float32, seeded)."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from recon.splat.cameras import PinholeCamera as Camera


def look_at(campos, target, up=(0.0, -1.0, 0.0)) -> torch.Tensor:
    """(4,4) world-to-camera in OpenCV axes (x right, y down, z forward) looking at target."""
    campos, target, up = (torch.tensor(v, dtype=torch.float64) for v in (campos, target, up))
    z = target - campos
    z = z / z.norm()
    x = torch.linalg.cross(z, up)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    rot = torch.stack([x, y, z])  # rows: camera axes in world
    view = torch.eye(4, dtype=torch.float64)
    view[:3, :3] = rot
    view[:3, 3] = -rot @ campos
    return view.float()


def default_camera(width=64, height=48, fx=58.0, fy=52.0, cx=None, cy=None) -> Camera:
    """A camera at (0.4,-0.3,-4) looking near the origin, fx != fy, slightly off-centre."""
    cx = 0.53 * width if cx is None else cx
    cy = 0.47 * height if cy is None else cy
    return Camera(look_at((0.4, -0.3, -4.0), (0.05, 0.02, 0.0)), fx, fy, cx, cy, width, height)


@dataclass
class Gaussians:
    means: torch.Tensor       # (N,3)
    quats: torch.Tensor       # (N,4)
    log_scales: torch.Tensor  # (N,3)
    opacities: torch.Tensor   # (N,)
    features: torch.Tensor    # (N,C) or (N,K,C)

    def tensors(self) -> list[torch.Tensor]:
        return [self.means, self.quats, self.log_scales, self.opacities, self.features]

    def to(self, dtype) -> "Gaussians":
        return Gaussians(*(t.detach().to(dtype) for t in self.tensors()))

    def requires_grad_(self) -> "Gaussians":
        for t in self.tensors():
            t.requires_grad_(True)
        return self


def random_gaussians(n: int, channels: int = 3, seed: int = 0, spread: float = 1.2,
                     scale_range=(0.02, 0.25), sh_coeffs: int | None = None) -> Gaussians:
    """n Gaussians around the origin: anisotropic, random rotation, opacity in [0.05, 0.95].

    sh_coeffs=K gives SH features (N,K,C) with a DC term in colour range and small higher terms.
    """
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) * 2 - 1) * spread
    quats = torch.randn(n, 4, generator=g)
    lo, hi = torch.log(torch.tensor(scale_range))
    log_scales = lo + (hi - lo) * torch.rand(n, 3, generator=g)
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g)
    if sh_coeffs is None:
        features = torch.rand(n, channels, generator=g)
    else:
        features = 0.3 * torch.randn(n, sh_coeffs, channels, generator=g)
        features[:, 0] = torch.rand(n, channels, generator=g)
    return Gaussians(means, quats, log_scales, opacities, features)
