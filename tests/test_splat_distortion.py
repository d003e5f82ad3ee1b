"""The rasterizer's distortion output (sum over pairs of w_i w_j (z_i - z_j)^2 per pixel) against
the dense float64 reference summed pair by pair, values and gradients (with distortion_moves False
the reference's depths are detached in the pair sum alone, so the depth terms must be left out
exactly for its gradients to match)."""
import pytest
import torch

from recon.splat import rasterization
from tests import splat_reference as ref
from tests.splat_compare import INPUTS, relative_error
from tests.splat_scenes import default_camera, random_gaussians

TOL = 1e-3


def overlapping(seed: int, sh_coeffs=None):
    """60 large, mostly opaque Gaussians at different depths: most pixels see several."""
    g = random_gaussians(60, 3, seed=seed, spread=0.8, scale_range=(0.1, 0.5), sh_coeffs=sh_coeffs)
    g.opacities = 0.3 + 0.6 * g.opacities
    return g


def distortion_and_grads(g, cam, reference: bool, sh_degree=None, moves=True, among=None):
    dtype = torch.float64 if reference else torch.float32
    params = g.to(dtype).requires_grad_()
    view = cam.viewmat.detach().clone().to(dtype).requires_grad_()
    gen = torch.Generator().manual_seed(3)
    weights = torch.rand(cam.height, cam.width, generator=gen, dtype=torch.float64)
    wimg = torch.rand(cam.height, cam.width, 3, generator=gen, dtype=torch.float64)
    if reference:
        r = ref.render(*params.tensors(), view, *cam.args()[1:], sh_degree=sh_degree, distortion=True,
                      distortion_moves=moves, distortion_among=among)
        spread, image = r["distortion"], r["image"]
    else:
        out = rasterization(*params.tensors(), view, *cam.args()[1:], sh_degree=sh_degree, distortion=True,
                            distortion_moves=moves, distortion_among=None if among is None else among.float())
        spread, image = out.distortion, out.image
    ((spread.double() * weights).sum() + 0.1 * (image.double() * wimg).sum()).backward()
    grads = {name: t.grad.double() for name, t in zip(INPUTS, params.tensors())}
    grads["viewmat"] = view.grad.double()
    return spread.detach().double(), image.detach().double(), grads


@pytest.mark.parametrize("sh_degree,moves", [(None, True), (1, True), (None, False)])
def test_distortion_and_its_gradients_match_pairwise_reference(sh_degree, moves):
    cam = default_camera(32, 24, fx=29.0, fy=26.0)
    g = overlapping(41, sh_coeffs=None if sh_degree is None else 4)
    ours, ours_img, ours_g = distortion_and_grads(g, cam, reference=False, sh_degree=sh_degree, moves=moves)
    theirs, theirs_img, theirs_g = distortion_and_grads(g, cam, reference=True, sh_degree=sh_degree, moves=moves)
    assert theirs.max() > 0.05, "the scene must spread weight in depth for the test to mean anything"
    assert (ours - theirs).abs().max() <= 1e-4 * max(1.0, theirs.max().item())
    # the two extra channels leave the image as it was
    assert (ours_img - theirs_img).abs().max() <= 1e-5
    errors = {k: relative_error(ours_g[k], theirs_g[k]) for k in ours_g}
    assert max(errors.values()) <= TOL, errors


@pytest.mark.parametrize("moves", [True, False])
def test_distortion_among_marked_gaussians_matches_reference_and_leaves_the_rest_out(moves):
    """A 0/1 mask counts only the pairs of marked Gaussians: values and gradients against the
    reference's pair sum weighted s_i s_j."""
    cam = default_camera(32, 24, fx=29.0, fy=26.0)
    g = overlapping(43)
    among = (torch.arange(60) % 3 != 0).double()
    ours, _, ours_g = distortion_and_grads(g, cam, reference=False, moves=moves, among=among)
    theirs, _, theirs_g = distortion_and_grads(g, cam, reference=True, moves=moves, among=among)
    everyone, _, _ = distortion_and_grads(g, cam, reference=True, moves=moves)
    assert theirs.max() > 0.05 and (everyone - theirs).abs().max() > 0.05, "the mask must change the sum"
    assert (ours - theirs).abs().max() <= 1e-4 * max(1.0, theirs.max().item())
    errors = {k: relative_error(ours_g[k], theirs_g[k]) for k in ours_g}
    assert max(errors.values()) <= TOL, errors


def test_distortion_among_nobody_is_zero_and_among_everyone_is_the_plain_sum():
    cam = default_camera(32, 24, fx=29.0, fy=26.0)
    g = overlapping(44)
    plain = rasterization(*g.tensors(), *cam.args(), distortion=True).distortion
    ones = rasterization(*g.tensors(), *cam.args(), distortion=True, distortion_among=torch.ones(60)).distortion
    zeros = rasterization(*g.tensors(), *cam.args(), distortion=True, distortion_among=torch.zeros(60)).distortion
    assert plain.max() > 0.05
    assert (ones - plain).abs().max() <= 1e-4 * plain.max().item()
    assert zeros.abs().max() == 0
    with pytest.raises(ValueError, match="distortion_among"):
        rasterization(*g.tensors(), *cam.args(), distortion=True, distortion_among=torch.ones(59))


def test_distortion_is_zero_for_one_surface_and_grows_with_depth_gap():
    """Two opaque discs facing the camera: at the same depth nothing is spread; a gap d costs
    w_front w_back d^2 on the pixels both cover."""
    cam = default_camera(32, 24, fx=29.0, fy=26.0)
    campos = -cam.viewmat[:3, :3].T @ cam.viewmat[:3, 3]
    axis = -campos / campos.norm()                   # from the camera towards the origin

    def spread_at(gap: float) -> torch.Tensor:
        means = torch.stack([torch.zeros(3), axis * gap])
        quats = torch.tensor([[1.0, 0, 0, 0]] * 2)
        log_scales = torch.full((2, 3), -1.0)
        out = rasterization(means, quats, log_scales, torch.tensor([0.5, 0.5]), torch.ones(2, 1),
                            cam.viewmat, *cam.args()[1:], distortion=True)
        return out.distortion

    assert spread_at(0.0).abs().max() < 1e-6
    centre = (int(cam.cy), int(cam.cx))
    small, large = spread_at(0.2)[centre].item(), spread_at(0.4)[centre].item()
    assert small > 0 and large == pytest.approx(4 * small, rel=0.05)
    # the centre pixel sees both at alpha ~ 0.5: w_front ~ 0.5, w_back ~ 0.25
    assert small == pytest.approx(0.5 * 0.25 * 0.2 ** 2, rel=0.1)


def test_without_distortion_output_is_none():
    g = random_gaussians(20, 3, seed=2)
    cam = default_camera(16, 12, fx=15.0, fy=13.0)
    assert rasterization(*g.tensors(), *cam.args()).distortion is None
