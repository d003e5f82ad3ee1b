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
separable 1-D convolutions (11 + 11 taps instead of 121).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F

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


def _blur(x: torch.Tensor, padding: int) -> torch.Tensor:
    """Separable Gaussian filter of (B, C, H, W), per channel, zero padding."""
    c = x.shape[1]
    g = _gauss_1d(x.dtype, str(x.device))
    x = F.conv2d(x, g.view(1, 1, WINDOW, 1).expand(c, 1, WINDOW, 1), padding=(padding, 0), groups=c)
    return F.conv2d(x, g.view(1, 1, 1, WINDOW).expand(c, 1, 1, WINDOW), padding=(0, padding), groups=c)


def ssim_map(a, b, convention: str = "3dgs") -> torch.Tensor:
    """Per-pixel SSIM (B, H', W', C); H' = H for '3dgs', H - 10 for 'skimage' (valid region)."""
    if convention not in ("3dgs", "skimage"):
        raise ValueError(f"convention must be '3dgs' or 'skimage', got {convention!r}")
    a, b = _pair(a, b)
    n, h, w, c = a.shape
    x = torch.cat([a, b, a * a, b * b, a * b], dim=-1).permute(0, 3, 1, 2)
    stats = _blur(x, WINDOW // 2 if convention == "3dgs" else 0)
    mu_a, mu_b, aa, bb, ab = stats.split(c, dim=1)
    var_a, var_b, cov = aa - mu_a * mu_a, bb - mu_b * mu_b, ab - mu_a * mu_b
    num = (2 * mu_a * mu_b + C1) * (2 * cov + C2)
    den = (mu_a * mu_a + mu_b * mu_b + C1) * (var_a + var_b + C2)
    return (num / den).permute(0, 2, 3, 1)


def ssim(a, b, mask=None, convention: str = "3dgs") -> torch.Tensor:
    """Mean SSIM (scalar tensor, differentiable); with a mask, the mean over masked pixels."""
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

