"""Motion priors (recon/dtg/priors.py) that price displacement."""
import torch

from recon.config import PriorConfig
from recon.dtg.priors import MotionPriors


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
