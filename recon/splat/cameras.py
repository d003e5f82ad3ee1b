"""Camera conventions: nerfstudio / transforms.json poses -> the rasterizer's viewmat."""
from __future__ import annotations

import math
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
    window: tuple[int, int, int, int] | None = None   # (x0, y0, W, H): a crop() of a W x H view

    @property
    def center(self) -> torch.Tensor:
        """(3,) camera centre in world coordinates."""
        r, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -r.T @ t

    def crop(self, x0: int, y0: int, width: int, height: int) -> "PinholeCamera":
        """The window [x0, x0 + width) x [y0, y0 + height) of this view as a camera of its own:
        its render is that window of the full render (the principal point moves, nothing else)."""
        if not (0 <= x0 and 0 <= y0 and 0 < width and 0 < height
                and x0 + width <= self.width and y0 + height <= self.height):
            raise ValueError(f"crop {width}x{height}+{x0}+{y0} is not inside a {self.width}x{self.height} view")
        ox, oy, full_w, full_h = self.window or (0, 0, self.width, self.height)
        return PinholeCamera(self.viewmat, self.fx, self.fy, self.cx - x0, self.cy - y0, width, height,
                             (ox + x0, oy + y0, full_w, full_h))

    def widened(self, margin: float) -> "PinholeCamera":
        """This view (or window) widened on each side by margin x the whole view's width and height
        (the same rays, more of them), as a window of the whole view widened alike, so the
        projection's clamp follows that view's edges as in the render."""
        x0, y0, w, h = self.window or (0, 0, self.width, self.height)
        mx, my = int(math.ceil(margin * w)), int(math.ceil(margin * h))
        return PinholeCamera(self.viewmat, self.fx, self.fy, self.cx + mx, self.cy + my,
                             self.width + 2 * mx, self.height + 2 * my, (x0, y0, w + 2 * mx, h + 2 * my))

    def downscaled(self, factor: int) -> "PinholeCamera":
        """This view at 1/factor of each side (pixel i covers pixels [i factor, (i+1) factor) of the
        original; sizes rounded down)."""
        if self.window is not None:
            raise ValueError("downscale a whole view, then crop it")
        f = float(factor)
        return PinholeCamera(self.viewmat, self.fx / f, self.fy / f, self.cx / f, self.cy / f,
                             self.width // factor, self.height // factor)

    def args(self) -> tuple:
        """Positional camera arguments of rasterization(), after the Gaussians (a crop's `window`
        goes by keyword)."""
        return (self.viewmat, self.fx, self.fy, self.cx, self.cy, self.width, self.height)
