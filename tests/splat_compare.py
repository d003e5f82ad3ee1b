"""Run recon.splat.rasterization and the dense float64 reference on the same inputs and compare."""
from __future__ import annotations

import torch

from recon.splat import rasterization
from tests import splat_reference as ref
from tests.splat_scenes import Camera, Gaussians

INPUTS = ("means", "quats", "log_scales", "opacities", "features")


def render_both(g: Gaussians, cam: Camera, **kw):
    """-> (ours RenderOutput, reference dict) without gradients."""
    with torch.no_grad():
        out = rasterization(*g.tensors(), *cam.args(), **kw)
        kw64 = {k: (v.double() if isinstance(v, torch.Tensor) else v) for k, v in kw.items()}
        r = ref.render(*g.to(torch.float64).tensors(), cam.viewmat.double(), *cam.args()[1:], **kw64)
    return out, r


def forward_errors(g: Gaussians, cam: Camera, **kw) -> dict[str, float]:
    """Max abs error of image, alpha, and depth (where the reference alpha > 1e-2)."""
    out, r = render_both(g, cam, **kw)
    covered = r["alpha"] > 1e-2
    depth_err = (out.depth.double() - r["depth"]).abs()[covered]
    return {
        "image": (out.image.double() - r["image"]).abs().max().item(),
        "alpha": (out.alpha.double() - r["alpha"]).abs().max().item(),
        "depth": depth_err.max().item() if depth_err.numel() else 0.0,
    }


def loss_weights(cam: Camera, channels: int, seed: int = 5):
    """Random positive weights so that every pixel of every output matters in the loss."""
    gen = torch.Generator().manual_seed(seed)
    shape = (cam.height, cam.width)
    return (torch.rand(*shape, channels, generator=gen, dtype=torch.float64),
            torch.rand(*shape, generator=gen, dtype=torch.float64),
            torch.rand(*shape, generator=gen, dtype=torch.float64))


def weighted_loss(image, alpha, depth, weights) -> torch.Tensor:
    wi, wa, wd = weights
    return (image.double() * wi).sum() + (alpha.double() * wa).sum() + 0.1 * (depth.double() * wd).sum()


def gradients(g: Gaussians, cam: Camera, reference: bool, depth: bool = True, **kw) -> dict[str, torch.Tensor]:
    """d weighted_loss / d every input (and viewmat, means2d), from ours or the reference;
    depth False: no loss on the depth image (its gradient reaches the backward as zeros)."""
    dtype = torch.float64 if reference else torch.float32
    params = g.to(dtype).requires_grad_()
    view = cam.viewmat.detach().clone().to(dtype).requires_grad_()
    kw = {k: (v.to(dtype) if isinstance(v, torch.Tensor) else v) for k, v in kw.items()}
    weights = loss_weights(cam, g.features.shape[-1])
    if not depth:
        weights = (weights[0], weights[1], torch.zeros_like(weights[2]))
    if reference:
        r = ref.render(*params.tensors(), view, *cam.args()[1:], **kw)
        r["means2d"].retain_grad()
        weighted_loss(r["image"], r["alpha"], r["depth"], weights).backward()
        means2d = r["means2d"]
    else:
        out = rasterization(*params.tensors(), view, *cam.args()[1:], **kw)
        weighted_loss(out.image, out.alpha, out.depth, weights).backward()
        means2d = out.means2d
    grads = {name: t.grad.double() for name, t in zip(INPUTS, params.tensors())}
    grads["viewmat"] = view.grad.double()
    grads["means2d"] = means2d.grad.double()
    return grads


def relative_error(a: torch.Tensor, b: torch.Tensor, floor: float = 1e-8) -> float:
    """||a - b|| / max(||b||, floor), b the reference; gradients with norm below `floor` count as
    zero (e.g. the rotation of a point-like Gaussian), so their relative error is not noise/noise."""
    return (a - b).norm().item() / max(b.norm().item(), floor)


def gradient_errors(g: Gaussians, cam: Camera, depth: bool = True, **kw) -> dict[str, float]:
    ours = gradients(g, cam, reference=False, depth=depth, **kw)
    theirs = gradients(g, cam, reference=True, depth=depth, **kw)
    return {k: relative_error(ours[k], theirs[k]) for k in ours}
