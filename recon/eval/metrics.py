"""Image metrics in torch: PSNR, SSIM (differentiable, usable as a loss) and thermal MAE.

Images are (H, W, C) or (H, W) — optionally with a leading batch dimension (B, H, W, C) —
float tensors in [0, 1] (thermal: temperature normalised with the dataset's thermal_range_k).
A mask (H, W) (or (B, H, W)) selects the pixels that count; masked-out pixels must still hold
finite values (fill them, e.g. with 0, in both images).

SSIM follows the 3DGS / E-D3DGS evaluation code (what the DTG literature reports): 11x11
Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, zero-padded convolution, mean over the
whole map and channels. `convention="skimage"` instead averages only where the window fits
inside the image, which equals skimage's structural_similarity(gaussian_weights=True,
sigma=1.5, use_sample_covariance=False) and pytorch_msssim. The window is applied as two
separable 1-D filters (11 + 11 taps instead of 121), natively where no autograd passes through.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F

from recon.eval import _native

WINDOW, SIGMA = 11, 1.5
C1, C2 = 0.01 ** 2, 0.03 ** 2


def _as_tensor(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        t = x
    else:
        arr = np.asarray(x)
        t = torch.from_numpy(arr if arr.flags.writeable else arr.copy())  # e.g. cached images
    return t if t.is_floating_point() or t.dtype == torch.bool else t.float()


def _bhwc(img: torch.Tensor) -> torch.Tensor:
    """(H, W) | (H, W, C) | (B, H, W, C) -> (B, H, W, C)."""
    if img.ndim == 2:
        return img[None, :, :, None]
    if img.ndim == 3:
        return img[None]
    if img.ndim == 4:
        return img
    raise ValueError(f"expected an image (H, W), (H, W, C) or (B, H, W, C), got shape {tuple(img.shape)}")


def _mask_bhw(mask, shape: torch.Size, device) -> torch.Tensor | None:
    if mask is None:
        return None
    m = _as_tensor(mask).to(device=device, dtype=torch.bool)
    m = m[None] if m.ndim == 2 else m
    if m.shape != shape[:3]:
        raise ValueError(f"mask shape {tuple(mask.shape)} does not match image {tuple(shape)}")
    return m


def _pair(a, b) -> tuple[torch.Tensor, torch.Tensor]:
    a, b = _bhwc(_as_tensor(a)), _bhwc(_as_tensor(b))
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    return a, b


def psnr(a, b, mask=None, data_range: float = 1.0) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB over all channels of the (masked) pixels; inf if equal."""
    a, b = _pair(a, b)
    sq = (a - b) ** 2
    m = _mask_bhw(mask, a.shape, a.device)
    mse = sq.mean() if m is None else sq[m].mean()
    return 10 * torch.log10(data_range ** 2 / mse)


@lru_cache(maxsize=8)
def _gauss_1d(dtype: torch.dtype, device: str) -> torch.Tensor:
    x = torch.arange(WINDOW, dtype=torch.float64) - WINDOW // 2
    g = torch.exp(-x ** 2 / (2 * SIGMA ** 2))
    return (g / g.sum()).to(dtype=dtype, device=device)


def _native_ok(*xs: torch.Tensor) -> bool:
    """CPU float32: what the native kernels take (anything else runs the torch code)."""
    return all(x.device.type == "cpu" and x.dtype == torch.float32 for x in xs)


def _blur(x: torch.Tensor, valid: bool = False) -> torch.Tensor:
    """Separable Gaussian filter of (B, H, W, K), per channel, zero padding; valid: only where the
    window fits (H - 10, W - 10). CPU float32 outside autograd (evaluation) runs the native kernel
    (`recon/eval/csrc/ssim.cpp`: ~3 against ~15 ms for 15 channels at 640x480); anything else
    torch's depthwise conv2d, with autograd."""
    r = WINDOW // 2
    if _native_ok(x) and not (torch.is_grad_enabled() and x.requires_grad):
        taps = _gauss_1d(torch.float32, "cpu").numpy()
        out = torch.from_numpy(_native.blur(x.detach().contiguous().numpy(), taps, torch.get_num_threads()))
        return out[:, r:-r, r:-r] if valid else out
    k, pad = x.shape[-1], 0 if valid else r
    g = _gauss_1d(x.dtype, str(x.device))
    y = x.permute(0, 3, 1, 2)  # a channels-last view: depthwise conv2d is 3x faster on it than planar
    y = F.conv2d(y, g.view(1, 1, WINDOW, 1).expand(k, 1, WINDOW, 1), padding=(pad, 0), groups=k)
    y = F.conv2d(y, g.view(1, 1, 1, WINDOW).expand(k, 1, 1, WINDOW), padding=(0, pad), groups=k)
    return y.permute(0, 2, 3, 1)


def _ssim_terms(a: torch.Tensor, b: torch.Tensor, valid: bool = False) -> tuple[torch.Tensor, ...]:
    """a, b: (B, H, W, C) -> mu_a, mu_b and the SSIM map's factors a1, a2 (numerator), b1, b2
    (denominator): SSIM = a1 a2 / (b1 b2)."""
    c = a.shape[-1]
    mu_a, mu_b, s_aa, s_bb, s_ab = _blur(torch.cat([a, b, a * a, b * b, a * b], -1), valid).split(c, -1)
    mu_ab, mu_aa, mu_bb = mu_a * mu_b, mu_a * mu_a, mu_b * mu_b
    a1, a2 = 2 * mu_ab + C1, 2 * (s_ab - mu_ab) + C2
    b1, b2 = mu_aa + mu_bb + C1, (s_aa - mu_aa) + (s_bb - mu_bb) + C2
    return mu_a, mu_b, a1, a2, b1, b2


def ssim_map(a, b, convention: str = "3dgs") -> torch.Tensor:
    """Per-pixel SSIM (B, H', W', C); H' = H for '3dgs', H - 10 for 'skimage' (valid region)."""
    if convention not in ("3dgs", "skimage"):
        raise ValueError(f"convention must be '3dgs' or 'skimage', got {convention!r}")
    a, b = _pair(a, b)
    _, _, a1, a2, b1, b2 = _ssim_terms(a, b, valid=convention == "skimage")
    return (a1 * a2) / (b1 * b2)


class _MeanSSIM(torch.autograd.Function):
    """Mean SSIM ('3dgs' convention) of a, b: (B, H, W, C), with its analytic backward.

    The zero-padded Gaussian blur G is self-adjoint (a symmetric kernel), so with S the SSIM map,
    dS/da = G(dS/dmu_a) + 2a G(dS/ds_aa) + b G(dS/ds_ab) (the form of fused-ssim, Mallick et al.):
    one blur of the 5C statistics forward and one of 3C channels back. On CPU float32 both passes
    are native and fused (`recon/eval/csrc/ssim.cpp`: no image-sized temporaries but the partials);
    elsewhere the same arithmetic in torch ops. Autograd through ssim_map recorded ~35 elementwise
    ops on strided tensors and two depthwise-convolution backwards.
    """

    @staticmethod
    def forward(ctx, a, b):
        ctx.native = _native_ok(a, b)
        if ctx.native:
            a, b = a.detach().contiguous(), b.detach().contiguous()
            total, partials = _native.ssim_forward(a.numpy(), b.numpy(), _gauss_1d(torch.float32, "cpu").numpy(),
                                                   torch.get_num_threads())
            ctx.save_for_backward(a, b, torch.from_numpy(partials))
            return a.new_tensor(total / a.numel())
        mu_a, mu_b, a1, a2, b1, b2 = _ssim_terms(a, b)
        smap = (a1 * a2) / (b1 * b2)
        ctx.save_for_backward(a, b, mu_a, mu_b, a1, a2, b1, b2, smap)
        return smap.mean()

    @staticmethod
    def backward(ctx, grad):
        need_a, need_b = ctx.needs_input_grad[:2]
        if ctx.native:
            a, b, partials = ctx.saved_tensors
            ga, gb = _native.ssim_backward(a.numpy(), b.numpy(), partials.numpy(), _gauss_1d(torch.float32, "cpu").numpy(),
                                           float(grad) / a.numel(), need_a, need_b, torch.get_num_threads())
            return (None if ga is None else torch.from_numpy(ga)), (None if gb is None else torch.from_numpy(gb))
        a, b, mu_a, mu_b, a1, a2, b1, b2, smap = ctx.saved_tensors
        g = grad / smap.numel()
        den = b1 * b2
        k = (a2 - a1) / den  # dS/dmu_a = 2 mu_b k - 2 mu_a t (t below), symmetric in b
        t = smap * (1 / b1 - 1 / b2)
        parts = [g * 2 * (mu_b * k - mu_a * t)] if need_a else []
        parts += [g * 2 * (mu_a * k - mu_b * t)] if need_b else []
        parts += [-g * smap / b2, g * 2 * a1 / den]  # dS/ds_aa (= dS/ds_bb), dS/ds_ab
        c = a.shape[-1]
        blurred = _blur(torch.cat(parts, -1)).split(c, -1)
        g_sq, g_ab = blurred[-2], blurred[-1]
        grad_a = blurred[0] + 2 * a * g_sq + b * g_ab if need_a else None
        grad_b = blurred[-3] + 2 * b * g_sq + a * g_ab if need_b else None
        return grad_a, grad_b


def ssim(a, b, mask=None, convention: str = "3dgs") -> torch.Tensor:
    """Mean SSIM (scalar tensor, differentiable); with a mask, the mean over masked pixels."""
    if mask is None and convention == "3dgs":  # the training loss: analytic backward
        return _MeanSSIM.apply(*_pair(a, b))
    smap = ssim_map(a, b, convention)
    m = _mask_bhw(mask, _bhwc(_as_tensor(a)).shape, smap.device)
    if m is None:
        return smap.mean()
    if convention == "skimage":
        r = WINDOW // 2
        m = m[:, r:-r, r:-r]
    return smap[m].mean()


def thermal_mae_k(pred_k, gt_k, valid=None) -> torch.Tensor:
    """Mean absolute temperature error in kelvin over valid pixels (default: finite GT)."""
    pred, gt = _as_tensor(pred_k), _as_tensor(gt_k)
    if pred.shape != gt.shape:
        raise ValueError(f"temperature maps differ in shape: {tuple(pred.shape)} vs {tuple(gt.shape)}")
    m = torch.isfinite(gt) if valid is None else _as_tensor(valid).to(torch.bool)
    return (pred[m] - gt[m]).abs().mean()

