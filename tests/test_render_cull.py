"""A Gaussian that holds the camera is not drawn from it (ModelConfig.cull_containing): its EWA
footprint has no meaning there, and a background Gaussian metres long filled a held-out view."""
import math

import torch

from recon import render as rendering
from recon.dtg.gaussians import quat_to_rotmat
from recon.scene import Camera
from recon.train.trainer import Trainer
from tests.test_train import small_cfg, tiny


def look_at_origin(distance: float = 2.0) -> Camera:
    """A 64x48 camera on the -z axis looking at the origin (OpenCV axes: +z forward)."""
    viewmat = torch.eye(4)
    viewmat[2, 3] = distance
    return Camera(viewmat, 60.0, 60.0, 32.0, 24.0, 64, 48)


def test_containing_is_the_mahalanobis_distance_of_the_camera_centre():
    gen = torch.Generator().manual_seed(0)
    n = 500
    means = torch.randn(n, 3, generator=gen)
    quats = torch.randn(n, 4, generator=gen)
    log_scales = torch.randn(n, 3, generator=gen) - 0.5
    camera = look_at_origin()
    k = 2.0
    got = rendering.containing(camera, means, quats, log_scales, k)
    # float64 reference: d^2 = (c - mu)^T Sigma^-1 (c - mu), Sigma = R S^2 R^T
    centre = torch.tensor([0.0, 0.0, -2.0], dtype=torch.float64)
    rot = quat_to_rotmat(quats.double())
    sigma = rot @ torch.diag_embed(torch.exp(2 * log_scales.double())) @ rot.transpose(1, 2)
    d = centre - means.double()
    d2 = torch.einsum("ni,nij,nj->n", d, torch.linalg.inv(sigma), d)
    near_boundary = (d2.sqrt() - k).abs() < 1e-4
    assert torch.equal(got[~near_boundary], (d2 < k * k)[~near_boundary])
    assert 0 < int(got.sum()) < n                       # both kinds are in the sample


def test_a_gaussian_holding_the_camera_is_left_out_and_the_rest_still_train(tmp_path_factory):
    scene = tiny(tmp_path_factory, "family-inside")
    tr = Trainer(small_cfg("dtg", iterations=100), scene, log=lambda _: None)
    model = tr.model
    view = scene.train["rgb"][0]
    camera = view.camera
    centre = camera.center
    g = model.gaussians
    with torch.no_grad():                             # Gaussian 0: 20 m wide, around the camera
        g["means"][0] = centre + torch.tensor([3.0, 0.0, 0.0])
        g["log_scales"][0] = math.log(20.0)
        g["opacity_rgb"][0] = 5.0
    model.cfg.cull_containing = None
    veiled, _, _ = rendering.render(model, "rgb", view.time, camera)
    model.cfg.cull_containing = 3.0
    image, out, _ = rendering.render(model, "rgb", view.time, camera)
    held = rendering.containing(camera, g["means"].detach(), g["quats"].detach(),
                                g["log_scales"].detach(), 3.0)
    assert held[0] and held.sum() < 5
    with torch.no_grad():
        g["opacity_rgb"][held] = -30.0                  # the same render without them
    model.cfg.cull_containing = None
    without, _, _ = rendering.render(model, "rgb", view.time, camera)
    assert (veiled - without).abs().mean() > 0.05       # the giant covers the view...
    assert torch.allclose(image, without, atol=1e-6)    # ...and is left out, as others that hold it
    model.cfg.cull_containing = 3.0
    image.sum().backward()
    grad = g["means"].grad
    assert grad[held].abs().sum() == 0 and grad[~held].abs().sum() > 0
