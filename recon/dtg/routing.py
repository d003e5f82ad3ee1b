"""Multimodal routing (DTG paper 3.4): each Gaussian is shared, rgb-only or thermal-only.

Logits l_i (N, 3) over ROLES = (shared, rgb, thermal). In training a Gumbel-softmax sample gives a
soft assignment s_soft; the forward pass uses its hard one-hot with the straight-through gradient.
Mask_rgb = shared + rgb, Mask_th = shared + thermal multiply each modality's opacity.

The schedule (fractions of the run): all shared until ``all_shared_until``; then logits learn with
prior p0 = prior_before; from ``specialise_from`` p0 goes linearly from prior_start to prior_end,
reached at ``freeze_at``, where routing freezes (argmax, no noise) and densification stops.
KL(mean s_soft || p0) keeps the population near the prior.
"""
from __future__ import annotations

import torch

from recon.config import RoutingConfig

SHARED, RGB_ONLY, THERMAL_ONLY = 0, 1, 2


def phase(cfg: RoutingConfig, progress: float) -> str:
    if progress < cfg.all_shared_until:
        return "shared"
    if progress < cfg.specialise_from:
        return "learn"
    if progress < cfg.freeze_at:
        return "specialise"
    return "frozen"


def prior(cfg: RoutingConfig, progress: float) -> torch.Tensor:
    """p0 (3,) at this progress."""
    if progress < cfg.specialise_from:
        return torch.tensor(cfg.prior_before)
    span = max(cfg.freeze_at - cfg.specialise_from, 1e-9)
    a = min((progress - cfg.specialise_from) / span, 1.0)
    start, end = torch.tensor(cfg.prior_start), torch.tensor(cfg.prior_end)
    return start + (end - start) * a


def gumbel_noise(shape, generator: torch.Generator | None) -> torch.Tensor:
    u = torch.rand(shape, generator=generator).clamp_(1e-10, 1 - 1e-10)
    return -torch.log(-torch.log(u))


def assignment(logits: torch.Tensor, tau: float, gumbel: torch.Tensor):
    """Gumbel-softmax with given noise (N, 3): reusing it lets both stages of one iteration see
    the same sample. -> (hard one-hot with straight-through gradient (N, 3), soft (N, 3))."""
    soft = torch.softmax((logits + gumbel) / tau, dim=1)
    hard = torch.nn.functional.one_hot(soft.argmax(1), 3).to(soft.dtype)
    return hard - soft.detach() + soft, soft


def hard_roles(logits: torch.Tensor) -> torch.Tensor:
    """Deterministic roles (N,) int64, as used when frozen and at inference."""
    return logits.argmax(1)


def masks(assignment: torch.Tensor) -> dict[str, torch.Tensor]:
    """assignment: (N, 3) one-hot (possibly straight-through) -> {'rgb': (N,), 'thermal': (N,)}"""
    return {"rgb": assignment[:, SHARED] + assignment[:, RGB_ONLY],
            "thermal": assignment[:, SHARED] + assignment[:, THERMAL_ONLY]}


def kl_to_prior(soft: torch.Tensor, p0: torch.Tensor) -> torch.Tensor:
    """KL(mean soft assignment || p0)."""
    mean = soft.mean(0).clamp_min(1e-8)
    return (mean * (mean.log() - p0.to(mean).log())).sum()


def role_counts(logits: torch.Tensor) -> dict[str, int]:
    roles = hard_roles(logits)
    return {"shared": int((roles == SHARED).sum()), "rgb": int((roles == RGB_ONLY).sum()),
            "thermal": int((roles == THERMAL_ONLY).sum())}
