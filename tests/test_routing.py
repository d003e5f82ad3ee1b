import torch

from recon.dtg import routing
from recon.config import RoutingConfig
from recon.dtg.time_embedding import TimeEmbedding, lerp_rows


def test_schedule_phases_and_prior():
    cfg = RoutingConfig()
    assert routing.phase(cfg, 0.0) == "shared"
    assert routing.phase(cfg, 0.1) == "learn"
    assert routing.phase(cfg, 0.5) == "specialise"
    assert routing.phase(cfg, 0.9) == "frozen"
    assert torch.allclose(routing.prior(cfg, 0.2), torch.tensor([0.8, 0.1, 0.1]))
    assert torch.allclose(routing.prior(cfg, 1 / 3), torch.tensor([0.5, 0.3, 0.2]))
    assert torch.allclose(routing.prior(cfg, 0.5), torch.tensor([0.325, 0.5, 0.175]))
    assert torch.allclose(routing.prior(cfg, 0.8), torch.tensor([0.15, 0.7, 0.15]))


def test_gumbel_straight_through_is_one_hot_with_soft_gradient():
    logits = torch.randn(100, 3, requires_grad=True)
    noise = routing.gumbel_noise(logits.shape, torch.Generator().manual_seed(0))
    hard, soft = routing.assignment(logits, 1.0, noise)
    assert torch.allclose(hard.sum(1), torch.ones(100))
    assert set(hard.detach().unique().tolist()) <= {0.0, 1.0}
    m = routing.masks(hard)
    (m["rgb"] * torch.arange(100.0)).sum().backward()
    assert logits.grad.abs().sum() > 0          # gradient reaches the logits through the soft sample


def test_sampled_roles_follow_logits():
    logits = torch.log(torch.tensor([0.8, 0.1, 0.1])).repeat(20000, 1)
    noise = routing.gumbel_noise(logits.shape, torch.Generator().manual_seed(0))
    hard, _ = routing.assignment(logits, 1.0, noise)
    freq = hard.mean(0)
    assert torch.allclose(freq, torch.tensor([0.8, 0.1, 0.1]), atol=0.02)   # Gumbel-max samples the softmax


def test_kl_zero_at_prior():
    p0 = torch.tensor([0.5, 0.3, 0.2])
    assert routing.kl_to_prior(p0.repeat(7, 1), p0).abs() < 1e-6
    assert routing.kl_to_prior(torch.tensor([[1.0, 0, 0]]), p0) > 0.5


def test_time_embedding_interpolates_and_smoothness_is_second_difference():
    table = torch.arange(5.0).view(5, 1).repeat(1, 2)
    assert torch.allclose(lerp_rows(table, 0.375), torch.tensor([1.5, 1.5]))
    te = TimeEmbedding(8, 4, 10)
    with torch.no_grad():
        te.coarse.copy_(torch.arange(4.0).view(4, 1).repeat(1, 4))     # linear in time
        te.fine.copy_(torch.arange(10.0).view(10, 1).repeat(1, 4) * 2)
    assert te.temporal_smoothness() < 1e-12        # a linear ramp has no second difference
    with torch.no_grad():
        te.fine[5] += 1
    assert te.temporal_smoothness() > 0
    assert te(0.3, progress=1.0).shape == (8,)
    assert te.fine_rows_at(0.0) == 4 and te.fine_rows_at(1.0) == 10
