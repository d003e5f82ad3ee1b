"""Analytic gradients of the native rasterizer vs autograd through the dense float64 reference
(relative error ||g - g_ref|| / ||g_ref|| <= 1e-3) and vs finite differences."""
import pytest
import torch

from recon.splat import rasterization
from tests import splat_reference as ref
from tests.splat_compare import INPUTS, gradient_errors, gradients, loss_weights, weighted_loss
from tests.splat_scenes import default_camera, random_gaussians

TOL = 1e-3


# 2 channels: the compositing loops' generic build (others are compiled per count)
@pytest.mark.parametrize("channels", [1, 2, 3])
def test_all_gradients_match_reference(channels):
    errors = gradient_errors(random_gaussians(300, channels, seed=10 + channels), default_camera(),
                             background=torch.linspace(0.2, 0.8, channels))
    assert max(errors.values()) <= TOL, errors


@pytest.mark.parametrize("channels", [1, 3])
def test_gradients_without_a_depth_loss_match_reference(channels):
    """Training takes no loss on depth: the backward then skips the depth terms."""
    errors = gradient_errors(random_gaussians(300, channels, seed=20 + channels), default_camera(),
                             depth=False, background=torch.linspace(0.2, 0.8, channels))
    assert max(errors.values()) <= TOL, errors


def test_gradients_match_reference_in_dense_scene():
    g = random_gaussians(200, 3, seed=7, spread=0.5, scale_range=(0.1, 0.6))
    g.opacities = 0.6 + 0.4 * g.opacities
    errors = gradient_errors(g, default_camera())
    assert max(errors.values()) <= TOL, errors


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("channels", [1, 3])
def test_sh_gradients_match_reference(degree, channels):
    g = random_gaussians(120, channels, seed=20 + degree, sh_coeffs=(degree + 1) ** 2)
    errors = gradient_errors(g, default_camera(), sh_degree=degree)
    assert max(errors.values()) <= TOL, errors


def test_means2d_grad_is_gradient_of_projected_means():
    """out.means2d.grad equals dL/d(projected mean) of the reference (what densification uses)."""
    g = random_gaussians(150, 3, seed=30)
    ours = gradients(g, default_camera(), reference=False)["means2d"]
    theirs = gradients(g, default_camera(), reference=True)["means2d"]
    assert ours.abs().sum() > 0
    assert (ours - theirs).norm() / theirs.norm() <= TOL


def _loss64(g, cam, name, index, value, sh_degree=None):
    """Reference (float64) weighted loss with one input entry replaced."""
    params = g.to(torch.float64)
    tensors = dict(zip(INPUTS, params.tensors()))
    tensors[name] = tensors[name].clone()
    tensors[name].view(-1)[index] = value
    r = ref.render(*(tensors[k] for k in INPUTS), cam.viewmat.double(), *cam.args()[1:], sh_degree=sh_degree)
    return weighted_loss(r["image"], r["alpha"], r["depth"], loss_weights(cam, g.features.shape[-1])).item()


def _loss32(g, cam, name, index, value, sh_degree=None):
    """Native (float32) weighted loss with one input entry replaced."""
    tensors = dict(zip(INPUTS, (t.detach().clone() for t in g.tensors())))
    tensors[name].view(-1)[index] = value
    with torch.no_grad():
        out = rasterization(*(tensors[k] for k in INPUTS), *cam.args(), sh_degree=sh_degree)
    return weighted_loss(out.image, out.alpha, out.depth, loss_weights(cam, g.features.shape[-1])).item()


@pytest.mark.parametrize("name", INPUTS)
def test_gradients_match_finite_differences(name):
    """Central differences on sampled entries: of the exact float64 function (tight), and of the
    native float32 forward itself (loose: float32 rounding and the 1/255 cut-off add noise)."""
    cam = default_camera(width=24, height=18, fx=22.0, fy=20.0)
    g = random_gaussians(12, 3, seed=40, spread=0.8, scale_range=(0.15, 0.5), sh_coeffs=4)
    grad = gradients(g, cam, reference=False, sh_degree=1)[name].reshape(-1)
    flat = getattr(g, name).detach().reshape(-1)
    picks = torch.argsort(grad.abs(), descending=True)[:6]  # entries with a real gradient
    for i in picks.tolist():
        x = flat[i].item()
        h64, h32 = 1e-5, 2e-4
        fd64 = (_loss64(g, cam, name, i, x + h64, 1) - _loss64(g, cam, name, i, x - h64, 1)) / (2 * h64)
        fd32 = (_loss32(g, cam, name, i, x + h32, 1) - _loss32(g, cam, name, i, x - h32, 1)) / (2 * h32)
        assert abs(grad[i].item() - fd64) <= 1e-3 * abs(fd64) + 1e-4, (name, i, grad[i].item(), fd64)
        assert abs(grad[i].item() - fd32) <= 3e-2 * abs(fd32) + 3e-2, (name, i, grad[i].item(), fd32)


def test_gradients_are_the_same_bits_every_run_and_thread_count():
    """Backward is deterministic (recon/splat/csrc/rasterize.cpp: per-pair records summed in tile
    order; projection: per-chunk camera sums): training repeats bit for bit. With per-thread
    buffers and dynamic tiles, 2 threads gave different last bits from run to run (and a
    500-iteration moving-box run 7.5-45 K on the same data). A dense scene with many Gaussians
    per tile and a wide image (many tiles to hand out) makes a different summation order show."""
    g = random_gaussians(3000, 3, seed=41, spread=1.5, scale_range=(0.05, 0.4))
    cam = default_camera(width=160, height=120, fx=140.0, fy=130.0)
    runs = [gradients(g, cam, reference=False, threads=t) for t in (1, 2, 2, 3, 2, 4, 2)]
    for other in runs[1:]:
        for k in runs[0]:
            assert torch.equal(runs[0][k], other[k]), k
