"""What of a view a training step renders: a coarser copy of it early in a run (coarse to fine)
and a random window of it (crop). The rasterizer's cost follows the pixels it renders (tiles
outside the window are never touched), so a 640x480 view trained through 320x240 windows costs
about what a 320x240 view does, while every pixel of the camera is still seen over the run; and a
coarse copy trains the early, large-scale fit at the cost of a small image.
"""
from __future__ import annotations

import torch

from recon.splat.cameras import PinholeCamera


def coarse_to_fine(levels: int, hold_at: float) -> tuple[tuple[float, int], ...]:
    """The resolution schedule ((from progress p, downscale factor), ...) of `levels` halvings:
    1/2^levels of each side until hold_at (where the schedule holds until held-out error has
    converged), then doubling at evenly spaced progress, full size for the last 1/levels of the
    rest: levels 2, hold_at 1/3 -> 4x until 1/3, 2x until 2/3, then full size."""
    if levels <= 0:
        return ((0.0, 1),)
    return ((0.0, 2 ** levels),) + tuple(
        (hold_at + (1 - hold_at) * i / levels, 2 ** (levels - 1 - i)) for i in range(levels))


def factor_at(schedule: tuple[tuple[float, int], ...], p: float) -> int:
    """The downscale factor of the schedule at progress p (entries in increasing start order)."""
    factor = 1
    for start, f in schedule:
        if start <= p:
            factor = f
    return factor


def downscale(camera: PinholeCamera, target: torch.Tensor, valid: torch.Tensor | None,
              factor: int) -> tuple[PinholeCamera, torch.Tensor, torch.Tensor | None]:
    """The view at 1/factor of each side: its camera, the target (H, W[, C]) averaged over each
    factor x factor block (thermal: over the block's valid pixels; a block without any is
    invalid). Rows and columns beyond a multiple of factor are dropped."""
    if factor <= 1:
        return camera, target, valid
    w, h = camera.width // factor, camera.height // factor
    if w < 1 or h < 1:
        raise ValueError(f"a {camera.width}x{camera.height} view cannot be downscaled {factor}x")
    block = target[: h * factor, : w * factor]
    if valid is None:
        small = block.reshape(h, factor, w, factor, *block.shape[2:]).mean((1, 3))
        return camera.downscaled(factor), small, None
    ok = valid[: h * factor, : w * factor].reshape(h, factor, w, factor).to(block.dtype)
    count = ok.sum((1, 3))
    total = (block.reshape(h, factor, w, factor) * ok).sum((1, 3))
    return camera.downscaled(factor), total / count.clamp_min(1), count > 0


def window(width: int, height: int, fraction: float, gen: torch.Generator) -> tuple[int, int, int, int]:
    """A window (x0, y0, w, h) of round(fraction x) each side of a width x height view: its centre
    drawn uniformly over the whole view, then the window shifted inside it. A uniform top-left
    corner (nerfstudio's and gsplat's patches) trains the border rarely: at fraction 0.5 of
    160x120 a pixel at the middle of the left edge is in 1.6 % of the windows and the centre pixel
    in 97 %; shifted centres give 19 % and 56 % (corner: 0.0 % and 5.5 %; 4000 draws)."""
    w = min(width, max(1, round(fraction * width)))
    h = min(height, max(1, round(fraction * height)))
    cx = float(torch.rand((), generator=gen)) * width
    cy = float(torch.rand((), generator=gen)) * height
    x0 = min(max(round(cx - w / 2), 0), width - w)
    y0 = min(max(round(cy - h / 2), 0), height - h)
    return x0, y0, w, h


def random_crop(camera: PinholeCamera, target: torch.Tensor, valid: torch.Tensor | None, fraction: float,
                gen: torch.Generator) -> tuple[PinholeCamera, torch.Tensor, torch.Tensor | None]:
    """The camera of a random window of the view and the window of its target (H, W[, C]) and
    valid mask (H, W) (None stays None). fraction >= 1: the whole view, no random draw."""
    if fraction >= 1.0:
        return camera, target, valid
    x0, y0, w, h = window(camera.width, camera.height, fraction, gen)
    rows, cols = slice(y0, y0 + h), slice(x0, x0 + w)
    return (camera.crop(x0, y0, w, h), target[rows, cols],
            None if valid is None else valid[rows, cols])
