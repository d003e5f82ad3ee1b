"""Densification ops keep every per-Gaussian tensor and its optimizer state the same length, and
children inherit their parent's values and Adam moments."""
import torch
from torch import nn

from recon.dtg import routing
from recon.config import DensifyConfig
from recon.dtg.strategy import Strategy, append, duplicate, remove, split


def make(n=10, seed=0):
    g = torch.Generator().manual_seed(seed)
    params = nn.ParameterDict({
        "means": nn.Parameter(torch.randn(n, 3, generator=g)),
        "quats": nn.Parameter(torch.randn(n, 4, generator=g)),
        "log_scales": nn.Parameter(torch.randn(n, 3, generator=g) - 2),
        "features_rgb": nn.Parameter(torch.randn(n, 1, 3, generator=g)),
        "opacity_rgb": nn.Parameter(torch.randn(n, generator=g)),
        "opacity_thermal": nn.Parameter(torch.randn(n, generator=g)),
        "embedding_rgb": nn.Parameter(torch.randn(n, 32, generator=g)),
        "route_logits": nn.Parameter(torch.randn(n, 3, generator=g)),
    })
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in params.items()], lr=1e-2)
    loss = sum((p ** 2).sum() for p in params.values())
    loss.backward()
    opt.step()
    return params, opt


def assert_consistent(params, opt):
    n = params["means"].shape[0]
    groups = {g["name"]: g["params"][0] for g in opt.param_groups}
    for k, p in params.items():
        assert p.shape[0] == n, k
        assert groups[k] is p, f"optimizer group {k} does not hold the live parameter"
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape, k


def test_duplicate_copies_rows_and_moments():
    params, opt = make()
    mask = torch.zeros(10, dtype=torch.bool)
    mask[[2, 7]] = True
    before = {k: p.detach().clone() for k, p in params.items()}
    m_before = opt.state[params["embedding_rgb"]]["exp_avg"].clone()
    duplicate(params, opt, mask)
    assert_consistent(params, opt)
    assert params["means"].shape[0] == 12
    for k in params:
        assert torch.equal(params[k][10:], before[k][mask])
    assert torch.equal(opt.state[params["embedding_rgb"]]["exp_avg"][10:], m_before[mask])


def test_append_adds_rows_with_fresh_moments():
    params, opt = make()
    before = {k: p.detach().clone() for k, p in params.items()}
    moments = opt.state[params["means"]]["exp_avg"].clone()
    rows = {k: torch.full((3, *p.shape[1:]), 7.0) for k, p in params.items()}
    append(params, opt, rows)
    assert_consistent(params, opt)
    assert params["means"].shape[0] == 13
    for k in params:
        assert torch.equal(params[k][:10], before[k]) and torch.equal(params[k][10:], rows[k])
    state = opt.state[params["means"]]
    assert torch.equal(state["exp_avg"][:10], moments) and not state["exp_avg"][10:].any()
    assert not state["exp_avg_sq"][10:].any()


def test_remove_and_split_keep_lengths():
    params, opt = make()
    mask = torch.zeros(10, dtype=torch.bool)
    mask[[0, 4, 5]] = True
    remove(params, opt, mask)
    assert_consistent(params, opt)
    assert params["means"].shape[0] == 7
    smask = torch.zeros(7, dtype=torch.bool)
    smask[[1, 3]] = True
    parent_scale = params["log_scales"].detach()[smask].clone()
    parent_logit = params["route_logits"].detach()[smask].clone()
    split(params, opt, smask, torch.Generator().manual_seed(1))
    assert_consistent(params, opt)
    assert params["means"].shape[0] == 7 - 2 + 4
    # children: scales / 1.6, same role logits as the parent
    assert torch.allclose(params["log_scales"][-4:-2], parent_scale - torch.log(torch.tensor(1.6)))
    assert torch.equal(params["route_logits"][-4:-2], parent_logit)
    assert torch.equal(params["route_logits"][-2:], parent_logit)


def test_role_aware_criterion_uses_own_modality():
    params, opt = make(n=3)
    params["route_logits"].data[:] = torch.tensor([[5.0, 0, 0], [0, 5.0, 0], [0, 0, 5.0]])
    s = Strategy(DensifyConfig(), ("rgb", "thermal"), 1.0, torch.Generator())
    radii = torch.ones(3, dtype=torch.int32)
    # rgb gradients large for all, thermal gradients zero
    s.accumulate("rgb", torch.full((3, 2), 1e-3), radii, 2, 2)
    s.accumulate("thermal", torch.zeros(3, 2), radii, 2, 2)
    roles = routing.hard_roles(params["route_logits"].detach())
    g = s.mean_grad(roles)
    own_rgb = (torch.tensor([1e-3, 1e-3]) * 1.0).norm()
    assert torch.isclose(g[1], own_rgb)            # rgb-only: its own gradient
    assert torch.isclose(g[0], own_rgb / 2)        # shared: pooled over both renders
    assert g[2] == 0                               # thermal-only: thermal gradient only


def test_step_densifies_within_budget_and_prunes_dead():
    params, opt = make(n=50)
    cfg = DensifyConfig(every=1, start=0.0, stop=1.0, grad_threshold=1e-6, max_gaussians=60)
    s = Strategy(cfg, ("rgb", "thermal"), 1.0, torch.Generator().manual_seed(0))
    params["opacity_rgb"].data[:5] = -20.0
    params["opacity_thermal"].data[:5] = -20.0
    radii = torch.ones(50, dtype=torch.int32)
    s.accumulate("rgb", torch.rand(50, 2), radii, 8, 8)
    s.accumulate("thermal", torch.rand(50, 2), radii, 8, 8)
    report = s.step(params, opt, iteration=1, progress=0.5)
    assert_consistent(params, opt)
    assert report["cloned"] + report["split"] <= 5       # room 10 -> at most 5 candidates
    assert params["means"].shape[0] <= 60
    assert report["pruned"] >= 5


def test_opacity_reset_caps_opacities_once_per_period_while_densifying():
    params, opt = make()
    strat = Strategy(DensifyConfig(opacity_reset_every=0.1, reset_opacity=0.01, start=0.03, stop=0.5),
                     ("rgb", "thermal"), 1.0, torch.Generator().manual_seed(0))
    with torch.no_grad():
        params["opacity_rgb"][:5] = -10.0          # already below the cap: kept
    low = params["opacity_rgb"].detach()[:5].clone()
    other = params["embedding_rgb"].detach().clone()
    assert not strat.reset_opacities(params, opt, 0.05)       # the first period is not over yet
    assert strat.reset_opacities(params, opt, 0.10)
    cap = torch.logit(torch.tensor(0.01))
    for m in ("rgb", "thermal"):
        p = params[f"opacity_{m}"]
        assert float(p.detach().max()) <= float(cap) + 1e-6
        assert not opt.state[p]["exp_avg"].any() and not opt.state[p]["exp_avg_sq"].any()
    assert torch.equal(params["opacity_rgb"].detach()[:5], low)
    assert torch.equal(params["embedding_rgb"].detach(), other)
    assert_consistent(params, opt)
    assert not strat.reset_opacities(params, opt, 0.15)        # once per period
    assert strat.reset_opacities(params, opt, 0.21)
    assert not strat.reset_opacities(params, opt, 0.55)        # densification is over


def test_opacity_reset_off_by_default_and_not_at_once_after_resume():
    params, opt = make()
    before = params["opacity_rgb"].detach().clone()
    strat = Strategy(DensifyConfig(), ("rgb", "thermal"), 1.0, torch.Generator())
    assert not any(strat.reset_opacities(params, opt, p) for p in (0.1, 0.2, 0.3))
    resumed = Strategy(DensifyConfig(opacity_reset_every=0.1), ("rgb", "thermal"), 1.0, torch.Generator())
    assert not resumed.reset_opacities(params, opt, 0.35)     # a run resumed mid-period waits for 0.4
    assert torch.equal(params["opacity_rgb"].detach(), before)
    assert resumed.reset_opacities(params, opt, 0.4)


def test_scale_bound_holds_the_largest_scale_and_is_off_by_default():
    params, _ = make(n=20)
    with torch.no_grad():
        params["log_scales"][:3] = 5.0                      # e^5 = 148 extents
    before = params["log_scales"].detach().clone()
    Strategy(DensifyConfig(), ("rgb", "thermal"), 2.0, torch.Generator()).bound_scales(params["log_scales"].data)
    assert torch.equal(params["log_scales"].detach(), before)
    Strategy(DensifyConfig(max_scale=0.5), ("rgb", "thermal"), 2.0,
             torch.Generator()).bound_scales(params["log_scales"].data)
    after = params["log_scales"].detach()
    assert torch.allclose(after[:3], torch.zeros(3, 3))     # log(0.5 x extent 2) = 0
    small = before < 0
    assert torch.equal(after[small], before[small])          # what fits stays as it was


def test_step_prunes_gaussians_larger_than_prune_scale():
    params, opt = make(n=30)
    with torch.no_grad():
        params["log_scales"][:4, 0] = 1.0                    # e = 2.7 extents along one axis
        params["opacity_rgb"][:] = params["opacity_thermal"][:] = 3.0     # none is dead
    cfg = DensifyConfig(every=1, start=0.0, stop=1.0, grad_threshold=1e9, prune_scale=0.1)
    s = Strategy(cfg, ("rgb", "thermal"), 1.0, torch.Generator().manual_seed(0))
    s.accumulate("rgb", torch.rand(30, 2), torch.ones(30, dtype=torch.int32), 8, 8)
    kept = params["log_scales"].detach()[4:].clone()
    report = s.step(params, opt, iteration=1, progress=0.5)
    assert_consistent(params, opt)
    big_left = params["log_scales"].detach().max(1).values > torch.log(torch.tensor(0.1))
    assert report["pruned"] == 4 + int((kept.max(1).values > torch.log(torch.tensor(0.1))).sum())
    assert not big_left.any()
