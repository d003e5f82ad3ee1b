"""Camera conventions: nerfstudio / transforms.json poses -> the rasterizer's viewmat."""
from __future__ import annotations

from dataclasses import dataclass

import torch

# camera axes OpenGL (x right, y up, z back) -> OpenCV (x right, y down, z forward)
_GL_TO_CV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


def viewmat_from_c2w_opengl(c2w) -> torch.Tensor:
    """c2w: (4,4) or (3,4) camera-to-world, OpenGL camera axes (transforms.json
    `transform_matrix`) -> (4,4) float32 world-to-camera in OpenCV axes (rasterization's
    viewmat). The rotation part must be orthonormal (a rigid pose)."""
    m = torch.as_tensor(c2w, dtype=torch.float64)
    if m.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"c2w must have shape (4,4) or (3,4), got {tuple(m.shape)}")
    c2w_cv = torch.eye(4, dtype=torch.float64)
    c2w_cv[:3] = m[:3]
    c2w_cv = c2w_cv @ _GL_TO_CV
    rot, pos = c2w_cv[:3, :3], c2w_cv[:3, 3]
    view = torch.eye(4, dtype=torch.float64)
    view[:3, :3] = rot.T
    view[:3, 3] = -rot.T @ pos
    return view.float()


@dataclass
class PinholeCamera:
    """A view for rasterization(): viewmat (4,4) world-to-camera in OpenCV axes, intrinsics in
    pixels (pixel (x, y) has its centre at (x + 0.5, y + 0.5))."""

    viewmat: torch.Tensor
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def center(self) -> torch.Tensor:
        """(3,) camera centre in world coordinates."""
        r, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -r.T @ t

    def args(self) -> tuple:
        """Positional camera arguments of rasterization(), after the Gaussians."""
        return (self.viewmat, self.fx, self.fy, self.cx, self.cy, self.width, self.height)
