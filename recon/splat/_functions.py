"""torch.autograd wrappers around the native kernels (recon.splat._native).

The native side takes and returns numpy buffers and knows nothing of torch; these Functions
move CPU tensors in and out without copies and wire the analytic VJPs into autograd.
"""
from __future__ import annotations

import numpy as np
import torch

from recon.splat import _native


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _t(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(a)


class Project(torch.autograd.Function):
    """Projection and (optionally) SH colour in one native pass.

    (means (N,3), quats (N,4), log_scales (N,3), opacities (N,), sh (N,K,C) or None, viewmat (4,4))
    -> means2d (N,2), conics (N,3), depths (N,), radii (N,) int32, colors (N,C) = max(SH_degree(dir)
    + 0.5, 0) for the direction camera -> mean, or None without sh.
    opacities only decide culling (non-differentiable here); radii are not differentiable.
    """

    @staticmethod
    def forward(ctx, means, quats, log_scales, opacities, sh, viewmat, intr: tuple, degree: int, threads: int):
        """intr: (fx, fy, cx, cy, width, height, near_plane, window (x0, y0, full_width, full_height),
        beside (< 0: off)): rasterization.intrinsics()."""
        sh_np = None if sh is None else _np(sh)
        means2d, conics, depths, radii, colors = _native.project_forward(
            _np(means), _np(quats), _np(log_scales), _np(opacities), _np(viewmat), *intr, sh_np, degree, threads
        )
        radii_t = _t(radii)
        colors_t = None if colors is None else _t(colors)
        ctx.save_for_backward(means, quats, log_scales, viewmat, radii_t, sh, colors_t)
        ctx.intr, ctx.degree, ctx.threads = intr, degree, threads
        ctx.mark_non_differentiable(radii_t)
        return _t(means2d), _t(conics), _t(depths), radii_t, colors_t

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, _v_radii, v_colors):
        means, quats, log_scales, viewmat, radii, sh, colors = ctx.saved_tensors
        has_sh = sh is not None
        v_means, v_quats, v_scales, v_view, v_sh = _native.project_backward(
            _np(means), _np(quats), _np(log_scales), _np(radii), _np(viewmat), *ctx.intr,
            _np(v_means2d), _np(v_conics), _np(v_depths), _np(sh) if has_sh else None,
            _np(colors) if has_sh else None, _np(v_colors) if has_sh else None, ctx.degree, ctx.threads,
        )
        return (_t(v_means), _t(v_quats), _t(v_scales), None, _t(v_sh) if has_sh else None, _t(v_view),
                None, None, None)


class Rasterize(torch.autograd.Function):
    """Projected Gaussians -> image (H,W,C) = sum w_i c_i, alpha (H,W), depth (H,W) = sum w_i z_i.

    w_i = alpha_i T_i, front to back by depth; background and depth normalisation are applied
    by the caller so autograd handles them.
    """

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, radii, width: int, height: int,
                max_pairs: int, threads: int):
        tensors = (means2d, conics, colors, opacities, depths, radii)
        image, alpha, depth, final_T, last, tx, ty, offsets, ids, boxes, _ = _native.rasterize_forward(
            *(_np(t) for t in tensors), width, height, max_pairs, threads
        )
        ctx.save_for_backward(*tensors)  # version-checked: in-place edits before backward raise
        ctx.state = (final_T, last, tx, ty, offsets, ids, boxes)
        ctx.size, ctx.threads = (width, height), threads
        return _t(image), _t(alpha), _t(depth)

    @staticmethod
    def backward(ctx, v_image, v_alpha, v_depth):
        grads = _native.rasterize_backward(
            *(_np(t) for t in ctx.saved_tensors), *ctx.size, *ctx.state, _np(v_image), _np(v_alpha), _np(v_depth), ctx.threads
        )
        v_means2d, v_conics, v_colors, v_opacities, v_depths = (_t(g) for g in grads)
        return v_means2d, v_conics, v_colors, v_opacities, v_depths, None, None, None, None, None
