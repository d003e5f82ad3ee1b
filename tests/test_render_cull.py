"""A Gaussian whose centre lies far beside the view is not drawn (`rasterization(cull_beside=m)`,
ModelConfig.cull_off_view): the projection clamps its Jacobian to the view's edge but keeps its
small depth, and a background Gaussian metres long then fills a held-out view."""
import math

import torch

from recon import render as rendering
from recon.splat import rasterization
from recon.train.trainer import Trainer
from tests.splat_compare import forward_errors, gradient_errors
from tests.splat_scenes import Gaussians, default_camera, random_gaussians
from tests.test_train import small_cfg, tiny


def _giants_at(us: list[float], vs: list[float], z: float = 1.0) -> Gaussians:
    """Gaussians 3 m wide centred where a camera at the origin looking +z (fx = fy = 50, cx = 32,
    cy = 24) puts their centre at pixel (u, v): each one covers a 64x48 view."""
    n = len(us)
    u, v = torch.tensor(us), torch.tensor(vs)
    means = torch.stack([(u - 32.0) / 50.0 * z, (v - 24.0) / 50.0 * z, torch.full((n,), z)], 1)
    return Gaussians(means, torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
                     torch.full((n, 3), math.log(3.0)), torch.full((n,), 0.5), torch.rand(n, 3))


def _visible(g: Gaussians, cull_beside, window=None, width=64, height=48) -> list[bool]:
    x0, y0 = window[:2] if window else (0, 0)
    out = rasterization(*g.tensors(), torch.eye(4), 50.0, 50.0, 32.0 - x0, 24.0 - y0, width, height,
                        window=None if window is None else (*window, 64, 48), cull_beside=cull_beside)
    return out.visible.tolist()


def test_the_cull_is_where_the_centre_projects_in_the_whole_view():
    # one view width (64 px) beyond the left edge is u = -64, beyond the right u = 128; one
    # height beyond the top v = -48
    g = _giants_at([-65.0, -63.0, 127.0, 129.0, 32.0, 32.0], [24.0, 24.0, 24.0, 24.0, -49.0, -47.0])
    assert _visible(g, None) == [True] * 6               # without the rule all of them cover the view
    assert _visible(g, 1.0) == [False, True, True, False, False, True]
    assert _visible(g, 0.5) == [False] * 6
    # a window decides as its whole view does
    assert _visible(g, 1.0, window=(16, 8), width=20, height=20) == [False, True, True, False, False, True]


def test_culled_gaussians_match_the_reference_and_take_no_gradient():
    """Against the float64 dense reference doing the same: a random scene plus large Gaussians
    placed beside the view, some beyond the margin and some within it."""
    cam = default_camera()
    g = random_gaussians(40, 3, seed=61)
    side = random_gaussians(12, 3, seed=62, scale_range=(0.8, 2.0))
    side.means = side.means * 0.2 + torch.tensor([0.4, -0.3, -4.0]) + torch.tensor([0.0, 0.0, 1.2])
    side.means[:, 0] += torch.linspace(-4.0, 4.0, 12)      # 1.2 m deep, up to 4 m to the side
    g = Gaussians(*(torch.cat([a, b]) for a, b in zip(g.tensors(), side.tensors())))
    kept = rasterization(*g.tensors(), *cam.args(), cull_beside=0.5).visible
    drawn = rasterization(*g.tensors(), *cam.args()).visible
    assert (drawn & ~kept).sum() >= 4 and kept[40:].sum() >= 2    # the rule decides for some
    errors = forward_errors(g, cam, cull_beside=0.5)
    assert max(errors.values()) <= 1e-4, errors
    grad_errors = gradient_errors(g, cam, cull_beside=0.5)
    assert max(grad_errors.values()) <= 1e-3, grad_errors
    g = g.requires_grad_()
    rasterization(*g.tensors(), *cam.args(), cull_beside=0.5).image.sum().backward()
    assert g.means.grad[drawn & ~kept].abs().sum() == 0


def test_a_model_far_beside_the_view_is_left_out_and_the_rest_still_train(tmp_path_factory):
    scene = tiny(tmp_path_factory, "family-inside")
    tr = Trainer(small_cfg("dtg", iterations=100), scene, log=lambda _: None)
    model = tr.model
    view = scene.train["rgb"][0]
    camera = view.camera
    g = model.gaussians
    rot, shift = camera.viewmat[:3, :3], camera.viewmat[:3, 3]
    with torch.no_grad():      # Gaussian 0: 0.3 m in front of the camera, 5 m to its left, 20 m long
        g["means"][0] = rot.T @ (torch.tensor([-5.0, 0.0, 0.3]) - shift)
        g["log_scales"][0] = math.log(20.0)
        g["opacity_rgb"][0] = 5.0
    model.cfg.cull_off_view = None
    veiled, out, _ = rendering.render(model, "rgb", view.time, camera)
    assert out.visible.shape[0] == g["means"].shape[0] and out.visible[0]   # rows are the model's
    model.cfg.cull_off_view = 1.0
    image, out, _ = rendering.render(model, "rgb", view.time, camera)
    assert not out.visible[0]
    with torch.no_grad():
        g["opacity_rgb"][0] = -30.0                      # the same render without it
    model.cfg.cull_off_view = None
    without, _, _ = rendering.render(model, "rgb", view.time, camera)
    assert (veiled - without).abs().mean() > 0.05        # the giant covers the view...
    assert torch.allclose(image, without, atol=1e-6)     # ...and is left out
    with torch.no_grad():
        g["opacity_rgb"][0] = 5.0
    model.cfg.cull_off_view = 1.0
    image, _, _ = rendering.render(model, "rgb", view.time, camera)
    image.sum().backward()
    grad = g["means"].grad
    assert grad[0].abs().sum() == 0 and grad[1:].abs().sum() > 0
