"""A Gaussian whose centre lies far beside the view is not drawn (ModelConfig.cull_off_view): the
projection clamps its Jacobian to the view's edge but keeps its small depth, and a background
Gaussian metres long then fills a held-out view."""
import math

import torch

from recon import render as rendering
from recon.scene import Camera
from recon.train.trainer import Trainer
from tests.test_train import small_cfg, tiny


def test_off_view_is_where_the_centre_projects_in_the_whole_view():
    camera = Camera(torch.eye(4), 50.0, 50.0, 32.0, 24.0, 64, 48)     # at the origin, looking +z
    # pixel u = 50 x / z + 32: one view width (64 px) beyond the left edge is u = -64
    xs = torch.tensor([-65.0, -63.0, 127.0, 129.0, 0.0, 0.0]) - 32.0
    means = torch.stack([xs / 50.0, torch.zeros(6), torch.ones(6)], 1)
    means[4] = torch.tensor([0.0, (-49.0 - 24.0) / 50.0, 1.0])         # v = -49: beyond -48
    means[5] = torch.tensor([-100.0, 0.0, -1.0])                       # behind the camera
    want = [True, False, False, True, True, False]
    assert rendering.off_view(camera, means, 1.0).tolist() == want
    # a window decides as its whole view does
    window = camera.crop(16, 8, 20, 20)
    assert rendering.off_view(window, means, 1.0).tolist() == want
    assert rendering.off_view(camera, means, 0.5).tolist() == [True, True, True, True, True, False]


def test_a_gaussian_far_beside_the_view_is_left_out_and_the_rest_still_train(tmp_path_factory):
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
    veiled, _, _ = rendering.render(model, "rgb", view.time, camera)
    model.cfg.cull_off_view = 1.0
    image, _, _ = rendering.render(model, "rgb", view.time, camera)
    beside = rendering.off_view(camera, g["means"].detach(), 1.0)
    assert beside[0] and beside.sum() < 10
    with torch.no_grad():
        g["opacity_rgb"][beside] = -30.0                 # the same render without them
    model.cfg.cull_off_view = None
    without, _, _ = rendering.render(model, "rgb", view.time, camera)
    assert (veiled - without).abs().mean() > 0.05        # the giant covers the view...
    assert torch.allclose(image, without, atol=1e-6)     # ...and is left out
    image.sum().backward()
    grad = g["means"].grad
    assert grad[beside].abs().sum() == 0 and grad[~beside].abs().sum() > 0
