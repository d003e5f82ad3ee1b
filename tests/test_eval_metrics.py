"""PSNR / SSIM / thermal MAE on known cases and against published reference values."""
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from recon.eval import psnr, ssim, thermal_mae_k
from recon.eval.metrics import ssim_map

CALIB = Path("/work/shared/data/lpips_calibration")
# data_tools_facts.md: skimage (== pytorch_msssim) and the 3DGS/E-D3DGS loss_utils.ssim
SKIMAGE = {"I03": 0.67317, "I04": 0.93252, "I06": 0.98963, "I08": 0.96743, "I19": 0.63073}
THREE_DGS = {"I03": 0.68190, "I04": 0.93120, "I06": 0.98977, "I08": 0.96890, "I19": 0.63958}
OFFICIAL_PSNR = {"I03": 21.11, "I04": 20.99, "I06": 27.01, "I08": 23.3, "I19": 21.62}


def _pair(name):
    if not (CALIB / "ref" / f"{name}.png").is_file():
        pytest.skip("TID2013 calibration pairs not available")
    read = lambda d: cv2.imread(str(CALIB / d / f"{name}.png"))[..., ::-1].astype(np.float32) / 255
    return torch.from_numpy(read("dist").copy()), torch.from_numpy(read("ref").copy())


def test_identical_images():
    img = torch.rand(20, 30, 3)
    assert math.isinf(float(psnr(img, img)))
    assert float(ssim(img, img)) == pytest.approx(1.0, abs=1e-6)
    kelvin = 290 + 30 * torch.rand(20, 30)
    assert float(thermal_mae_k(kelvin, kelvin)) == 0.0


def test_known_gaussian_noise_gives_the_expected_psnr():
    gen = torch.Generator().manual_seed(0)
    clean = torch.full((240, 320, 3), 0.5)
    sigma = 0.05  # 10 sigma from 0 and 1: no clipping
    noisy = clean + sigma * torch.randn(clean.shape, generator=gen)
    assert float(psnr(noisy, clean)) == pytest.approx(20 * math.log10(1 / sigma), abs=0.1)
    assert float(psnr(noisy * 300, clean * 300, data_range=300.0)) == pytest.approx(26.02, abs=0.1)


def test_uniform_one_kelvin_offset_gives_mae_1():
    gt = 280 + 50 * torch.rand(24, 32)
    gt[0, :5] = float("nan")  # no measurement: ignored by default
    assert float(thermal_mae_k(gt + 1.0, gt)) == pytest.approx(1.0, abs=1e-4)
    valid = torch.zeros(24, 32, dtype=torch.bool)
    valid[5:10] = True
    pred = gt.clone()
    pred[~valid] += 7.0
    assert float(thermal_mae_k(pred, gt, valid)) == 0.0


def test_psnr_matches_the_official_calibration_values():
    for name, expected in OFFICIAL_PSNR.items():
        a, b = _pair(name)
        assert float(psnr(a, b)) == pytest.approx(expected, abs=0.01)


@pytest.mark.parametrize("name", list(SKIMAGE))
def test_ssim_matches_skimage_and_3dgs_reference_values(name):
    a, b = _pair(name)
    assert float(ssim(a, b)) == pytest.approx(THREE_DGS[name], abs=1e-4)
    assert float(ssim(a, b, convention="skimage")) == pytest.approx(SKIMAGE[name], abs=1e-4)


def test_separable_ssim_equals_the_dense_3dgs_formula():
    """The 3DGS loss_utils.ssim written out with a full 11x11 window, zero padding."""
    a, b = torch.rand(37, 41, 3, dtype=torch.float64), torch.rand(37, 41, 3, dtype=torch.float64)
    x = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-x ** 2 / (2 * 1.5 ** 2))
    g = g / g.sum()
    window = (g[:, None] @ g[None, :]).expand(3, 1, 11, 11)
    conv = lambda t: F.conv2d(t, window, padding=5, groups=3)
    i1, i2 = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    mu1, mu2 = conv(i1), conv(i2)
    s11, s22, s12 = conv(i1 * i1) - mu1 ** 2, conv(i2 * i2) - mu2 ** 2, conv(i1 * i2) - mu1 * mu2
    ref = ((2 * mu1 * mu2 + 1e-4) * (2 * s12 + 9e-4)) / ((mu1 ** 2 + mu2 ** 2 + 1e-4) * (s11 + s22 + 9e-4))
    assert float(ssim(a, b)) == pytest.approx(float(ref.mean()), abs=1e-10)


def test_native_blur_equals_the_float64_convolution():
    """The native separable blur (CPU float32, no autograd) against torch's conv2d in float64: the
    same zero padding at every edge, images smaller than the window, batches, valid crops."""
    from recon.eval.metrics import _blur

    torch.manual_seed(3)
    for shape in [(1, 37, 41, 15), (2, 9, 7, 3), (1, 4, 3, 1), (1, 120, 160, 9)]:
        x = torch.rand(*shape)
        for valid in (False, True) if min(shape[1:3]) > 10 else (False,):
            native = _blur(x, valid)
            ref = _blur(x.double(), valid)  # float64 takes the conv2d path
            assert native.dtype == torch.float32 and native.shape == ref.shape, (shape, valid)
            assert float((native.double() - ref).abs().max()) < 1e-6, (shape, valid)
    x = torch.rand(1, 12, 13, 2, requires_grad=True)  # autograd needed: conv2d, gradients flow
    _blur(x).sum().backward()
    assert x.grad is not None and float(x.grad.abs().sum()) > 0


def test_native_ssim_loss_equals_the_float64_torch_path():
    """The fused native SSIM (CPU float32) against the same arithmetic in torch ops in float64:
    the value, and the gradient of a render against a fixed target (training) or of both."""
    torch.manual_seed(5)
    for shape in [(1, 48, 64, 3), (2, 13, 9, 1), (1, 5, 4, 3)]:
        a, b = torch.rand(*shape), torch.rand(*shape)
        a32, a64 = a.clone().requires_grad_(), a.double().requires_grad_()
        v32, v64 = ssim(a32, b), ssim(a64, b.double())
        assert abs(float(v32.detach()) - float(v64.detach())) < 1e-6, shape
        (g32,), (g64,) = torch.autograd.grad(v32, (a32,)), torch.autograd.grad(v64, (a64,))
        assert float((g32.double() - g64).norm() / g64.norm()) < 1e-5, shape
        b32, b64 = b.clone().requires_grad_(), b.double().requires_grad_()
        gb32 = torch.autograd.grad(ssim(a, b32), (b32,))[0]
        gb64 = torch.autograd.grad(ssim(a.double(), b64), (b64,))[0]
        assert float((gb32.double() - gb64).norm() / gb64.norm()) < 1e-5, shape


def test_ssim_is_differentiable_and_a_usable_loss():
    torch.manual_seed(0)
    a = torch.rand(12, 14, 1, dtype=torch.float64, requires_grad=True)
    b = torch.rand(12, 14, 1, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,))
    pred = torch.rand(24, 24, 3, requires_grad=True)
    target = torch.rand(24, 24, 3)
    opt = torch.optim.Adam([pred], lr=0.05)
    start = float(ssim(pred, target).detach())
    for _ in range(30):
        opt.zero_grad()
        (1 - ssim(pred, target)).backward()
        opt.step()
    assert float(ssim(pred, target).detach()) > start + 0.3


def test_ssim_analytic_backward_equals_autograd_through_the_map():
    """ssim() (no mask) has its own backward (the blur is self-adjoint); it must give autograd's
    gradients through ssim_map, for either input, any channel count and batch, in float32 too."""
    torch.manual_seed(1)
    for shape, dtype, tol in [((2, 19, 23, 3), torch.float64, 1e-12), ((120, 160, 3), torch.float32, 1e-5),
                              ((30, 20, 1), torch.float32, 1e-5)]:
        a = torch.rand(*shape, dtype=dtype, requires_grad=True)
        b = torch.rand(*shape, dtype=dtype, requires_grad=True)
        ga, gb = torch.autograd.grad(ssim(a, b), (a, b))
        ra, rb = torch.autograd.grad(ssim_map(a, b).mean(), (a, b))
        for g, r in ((ga, ra), (gb, rb)):
            assert float((g - r).norm() / r.norm()) < tol, shape
    a = torch.rand(9, 11, 2, dtype=torch.float64, requires_grad=True)
    b = torch.rand(9, 11, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(ssim, (a, b))


def test_masks_select_pixels_and_batches_average():
    a, b = torch.rand(16, 20, 3), torch.rand(16, 20, 3)
    mask = torch.zeros(16, 20, dtype=torch.bool)
    mask[3:9, 4:15] = True
    b_far = b.clone()
    b_far[~mask] = 1 - a[~mask]  # wildly different outside the mask
    sq = ((a - b) ** 2)[mask].mean()
    assert float(psnr(a, b_far, mask)) == pytest.approx(float(-10 * torch.log10(sq)), rel=1e-5)
    assert float(ssim(a, b, mask)) == pytest.approx(float(ssim_map(a, b)[0][mask].mean()), rel=1e-6)
    batch = ssim(torch.stack([a, b]), torch.stack([b, b]))
    assert float(batch) == pytest.approx((float(ssim(a, b)) + 1.0) / 2, rel=1e-6)
    with pytest.raises(ValueError, match="shape"):
        ssim(a, b[:-1])
