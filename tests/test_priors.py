"""Priors (recon/dtg/priors.py): the ones that price displacement, and one temperature per body."""
import pytest
import torch

from recon.config import PriorConfig
from recon.dtg.priors import MotionPriors, body_warmth


def test_residual_sparsity_prices_the_network_residual_not_the_bodies_motion():
    """PriorConfig.residual_sparsity: the mean norm of the geometry residuals (in scene extents),
    whatever else moved the Gaussians; the plain sparsity term prices the whole displacement."""
    gen = torch.Generator().manual_seed(0)
    n, extent = 500, 4.0
    canonical = {"means": torch.randn(n, 3, generator=gen), "quats": torch.randn(n, 4, generator=gen)}
    residual = (0.1 * torch.randn(n, 3, generator=gen)).requires_grad_()
    body_motion = torch.zeros(n, 3)
    body_motion[: n // 2] = torch.tensor([2.0, 0.0, 0.0])         # half the Gaussians ride a body
    deformed = {"means": canonical["means"] + body_motion + residual, "quats": canonical["quats"],
                "geometry_residuals": {"means": residual}}
    priors = MotionPriors(PriorConfig(residual_sparsity=0.5, sample=n), extent)
    assert priors.enabled
    loss, stats = priors(canonical, deformed, None, 0.5, 0.1, gen)
    expected = float((residual.detach() / extent).norm(dim=1).mean())
    assert abs(stats["residual"] - expected) < 1e-6
    assert abs(float(loss.detach()) - 0.5 * expected) < 1e-6
    loss.backward()
    cosine = torch.nn.functional.cosine_similarity(residual.grad, residual.detach(), dim=1)
    assert (cosine > 0.999).all()                                 # descent shrinks every residual
    whole, stats = MotionPriors(PriorConfig(sparsity=0.5, sample=n), extent)(canonical, deformed, None, 0.5, 0.1, gen)
    assert stats["sparse"] > 2 * stats.get("residual", 0) + 0.2   # the bodies' motion is priced there


def test_body_warmth_pulls_only_members_beyond_the_band_towards_their_own_bodys_median():
    """A hot body (0.9) with one member at the background's temperature (0.2) and a cold body
    (0.1) whose members lie within the band: only the hot body's outlier pays, 0.6 beyond the band
    over 5 members, and its gradient warms it; static Gaussians and closed gates are free."""
    colour = torch.tensor([0.9, 0.92, 0.2, 0.5, 0.1, 0.12, 0.0], requires_grad=True)
    basis = torch.tensor([1, 1, 1, 0, 2, 2, 1.0])
    members = torch.tensor([True, True, True, True, True, True, False])      # the last: gate closed
    warmth = body_warmth(colour, basis, members, 0.1)
    assert float(warmth.detach()) == pytest.approx(0.6 / 5, rel=1e-5)
    warmth.backward()
    assert float(colour.grad[2]) < 0 and float(colour.grad[[0, 1, 3, 4, 5, 6]].abs().sum()) == 0
    none = body_warmth(colour, torch.zeros(7), members, 0.1)
    assert float(none.detach()) == 0
