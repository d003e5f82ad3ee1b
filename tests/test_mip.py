"""ModelConfig.mip_filter: Mip-Splatting's 3D smoothing filter (recon/dtg/mip.py)."""
import math

import torch

from recon.dtg.mip import filtered, sampling_variance
from recon.splat.cameras import PinholeCamera
from recon.splat.ply import read_gaussians_ply
from recon.export import export_ply
from recon.train.trainer import MIP_EVERY, Trainer
from tests.test_train import scene, small_cfg  # noqa: F401  (scene: a module fixture)


def _camera(position, fx=100.0, width=80, height=60) -> PinholeCamera:
    """Looking down +z (OpenCV axes, no rotation) from `position`."""
    view = torch.eye(4)
    view[:3, 3] = -torch.tensor(position, dtype=torch.float32)
    return PinholeCamera(view, fx, fx, width / 2, height / 2, width, height)


def test_filter_widens_each_axis_by_the_variance_and_keeps_the_integral():
    gen = torch.Generator().manual_seed(0)
    log_scales = torch.randn(50, 3, generator=gen, dtype=torch.float64) * 2 - 4
    opacities = torch.rand(50, generator=gen, dtype=torch.float64)
    variance = torch.rand(50, generator=gen, dtype=torch.float64) * 1e-3
    wide, opac = filtered(log_scales, opacities, variance)
    assert torch.allclose(torch.exp(2 * wide), torch.exp(2 * log_scales) + variance[:, None])
    # a Gaussian's integral is opacity x sqrt(det covariance) x (2 pi)^(3/2): unchanged
    assert torch.allclose(opac * torch.exp(wide.sum(1)), opacities * torch.exp(log_scales.sum(1)))
    assert (opac <= opacities).all()
    # a thin Gaussian (1e-4 against a filter of 0.03) loses most of its peak; a wide one nothing
    w, o = filtered(torch.tensor([[math.log(1e-4)] * 3, [0.0] * 3]), torch.ones(2), torch.full((2,), 9e-4))
    assert float(o[0]) < 1e-6 and abs(float(o[1]) - 1) < 2e-3
    same = filtered(log_scales, opacities, torch.zeros(50, dtype=torch.float64))
    assert torch.allclose(same[0], log_scales) and torch.allclose(same[1], opacities)
    inputs = (log_scales[:4].clone().requires_grad_(), opacities[:4].clone().requires_grad_())
    assert torch.autograd.gradcheck(lambda s, o: filtered(s, o, variance[:4]), inputs)


def test_sampling_variance_follows_the_view_that_samples_finest():
    far, near = _camera([0.0, 0.0, 0.0]), _camera([0.0, 0.0, 1.0], fx=50.0)
    points = torch.tensor([[0.0, 0.0, 4.0],     # depth 4 at f 100 (rate 25) and 3 at f 50 (rate 16.7)
                           [0.0, 0.0, 1.5],     # depth 1.5 at f 100 (66.7) and 0.5 at f 50 (100)
                           [0.0, 0.0, -2.0],    # behind both
                           [30.0, 0.0, 3.0]])   # far beside both views
    v = sampling_variance(points, [far, near], 0.2)
    assert math.isclose(float(v[0]), 0.2 * (4 / 100) ** 2, rel_tol=1e-5)
    assert math.isclose(float(v[1]), 0.2 * (0.5 / 50) ** 2, rel_tol=1e-5)
    # points no view sees take the largest value of the seen ones (Mip-Splatting's rule)
    assert float(v[2]) == float(v[3]) == float(v[0])
    # just beyond the view's edge (within the 15 % margin) still counts as seen
    edge = torch.tensor([[0.45 * 4 * 80 / 100 + 0.2, 0.0, 4.0]])
    assert math.isclose(float(sampling_variance(edge, [far], 0.2)[0]), 0.2 * (4 / 100) ** 2, rel_tol=1e-5)
    assert float(sampling_variance(points[2:3], [far], 0.2)[0]) == 0.0


def test_trainer_keeps_the_filter_on_every_gaussian_through_densification_and_resume(scene, tmp_path):
    cfg = small_cfg(iterations=2 * MIP_EVERY, threads=2)
    cfg.model.mip_filter = 0.2
    a = Trainer(cfg, scene, tmp_path, log=lambda _: None)
    g = a.model.gaussians
    cameras = {m: [v.camera for v in scene.train[m]] for m in ("rgb", "thermal")}
    for m in ("rgb", "thermal"):
        assert not g[f"mip_{m}"].requires_grad
        assert torch.equal(g[f"mip_{m}"], sampling_variance(g["means"], cameras[m], 0.2))
    n0 = a.model.num_gaussians
    for _ in range(MIP_EVERY):
        a.step()
    g = a.model.gaussians
    assert a.model.num_gaussians != n0          # densification ran, and the filter followed it
    for m in ("rgb", "thermal"):
        assert g[f"mip_{m}"].shape == (a.model.num_gaussians,)
        assert torch.equal(g[f"mip_{m}"], sampling_variance(g["means"], cameras[m], 0.2))
        assert float(g[f"mip_{m}"].min()) > 0
    # the render takes it: a filtered Gaussian is wider and fainter than its raw parameters
    with torch.no_grad():
        inputs = a.model.render_inputs("rgb", 0.5)
        assert (inputs["log_scales"] > g["log_scales"]).all()
        assert (inputs["opacities"] < torch.sigmoid(g["opacity_rgb"])).all()
    a.save_checkpoint(tmp_path / "ck.pt")
    b = Trainer.resume(tmp_path / "ck.pt", scene, tmp_path, log=lambda _: None)
    for _ in range(MIP_EVERY // 2):
        a.step()
        b.step()
    for k, p in a.model.gaussians.items():
        assert torch.equal(p, b.model.gaussians[k]), k
    # the export bakes the RGB filter into the canonical scales and opacity
    export_ply(a.model, tmp_path / "m.ply")
    ply = read_gaussians_ply(tmp_path / "m.ply")
    with torch.no_grad():
        wide, opac = filtered(g["log_scales"], torch.sigmoid(g["opacity_rgb"]), g["mip_rgb"])
    assert torch.allclose(torch.from_numpy(ply.log_scales), wide, atol=1e-6)
    assert torch.allclose(torch.sigmoid(torch.from_numpy(ply.opacity_logits)), opac, atol=1e-6)
