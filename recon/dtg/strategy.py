"""Structure-consistent densification and pruning (3DGS; DTG paper 3.4).

Generic ops (as gsplat's strategy ops): ``duplicate``, ``split`` and ``remove`` act on *every*
tensor in the model's per-Gaussian dict and on its optimizer state, so a new attribute (another
modality's colour, a routing logit) needs no change here. Children inherit everything from their
parent: role logits, embeddings, both opacities and the Adam moments.

Statistics are kept per modality: each modality's render gives its own screen-space mean
gradients. Shared Gaussians densify by the pooled gradient of both modalities, rgb-only and
thermal-only ones by their own modality's gradient only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from recon.dtg import routing
from recon.config import DensifyConfig
from recon.dtg.gaussians import quat_to_rotmat


# ---------------------------------------------------------------- generic ops on every tensor
def _swap(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, param_fn, state_fn=None) -> None:
    """Replace each per-Gaussian parameter p by param_fn(key, p) and its per-row Adam moments m by
    state_fn(key, m) (default: param_fn)."""
    state_fn = state_fn or param_fn
    for key in list(model_params.keys()):
        old = model_params[key]
        new = nn.Parameter(param_fn(key, old.detach()), requires_grad=old.requires_grad)
        for group in optimizer.param_groups:
            if group["params"][0] is old:
                group["params"][0] = new
                state = optimizer.state.pop(old, None)
                if state:
                    optimizer.state[new] = {
                        k: (state_fn(key, v) if torch.is_tensor(v) and v.dim() > 0 and v.shape[0] == old.shape[0] else v)
                        for k, v in state.items()}
        model_params[key] = new


@torch.no_grad()
def swap_parameter(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, key: str,
                   param_fn, state_fn=None) -> None:
    """Replace one per-Gaussian parameter (and its Adam moments) with a reshaped version of itself,
    e.g. trajectories with more knots."""
    _swap(model_params, optimizer, lambda k, x: param_fn(x) if k == key else x,
          lambda k, x: (state_fn or param_fn)(x) if k == key else x)


@torch.no_grad()
def duplicate(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, mask: torch.Tensor) -> None:
    """Append a copy of the rows in mask (N,) bool."""
    _swap(model_params, optimizer, lambda _, x: torch.cat([x, x[mask]]))


@torch.no_grad()
def append(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, rows: dict[str, torch.Tensor]) -> None:
    """Append new Gaussians: rows holds every per-Gaussian tensor's new rows (same keys as the
    model); their Adam moments start at zero."""
    _swap(model_params, optimizer, lambda k, x: torch.cat([x, rows[k].to(x.dtype)]),
          lambda k, m: torch.cat([m, torch.zeros((len(rows[k]), *m.shape[1:]), dtype=m.dtype)]))


@torch.no_grad()
def remove(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, mask: torch.Tensor) -> None:
    """Drop the rows in mask (N,) bool."""
    keep = ~mask
    _swap(model_params, optimizer, lambda _, x: x[keep])


@torch.no_grad()
def split(model_params: nn.ParameterDict, optimizer: torch.optim.Optimizer, mask: torch.Tensor,
          generator: torch.Generator, n_children: int = 2, shrink: float = 1.6) -> None:
    """Replace each Gaussian in mask by n_children samples of itself, scales / shrink (3DGS)."""
    idx = mask.nonzero()[:, 0]
    means, quats, log_scales = (model_params[k].detach()[idx] for k in ("means", "quats", "log_scales"))
    scales = log_scales.exp()
    noise = torch.randn((n_children, idx.numel(), 3), generator=generator) * scales
    child_means = (means + torch.einsum("nij,cnj->cni", quat_to_rotmat(quats), noise)).reshape(-1, 3)
    child_log_scales = (log_scales - torch.log(torch.tensor(shrink))).repeat(n_children, 1)
    keep = ~mask

    def inherit(_, x):
        return torch.cat([x[keep], x[idx].repeat(n_children, *[1] * (x.dim() - 1))])

    def place(key, x):
        if key == "means":
            return torch.cat([x[keep], child_means])
        if key == "log_scales":
            return torch.cat([x[keep], child_log_scales])
        return inherit(key, x)

    _swap(model_params, optimizer, place, inherit)


# ---------------------------------------------------------------- the strategy
@dataclass
class DensifyStats:
    """Per-modality sums of NDC-scaled screen-space gradient norms and visibility counts."""
    grad: dict[str, torch.Tensor] = field(default_factory=dict)
    count: dict[str, torch.Tensor] = field(default_factory=dict)

    def reset(self, n: int, modalities) -> None:
        self.grad = {m: torch.zeros(n) for m in modalities}
        self.count = {m: torch.zeros(n) for m in modalities}


class Strategy:
    """3DGS densification made role-aware. Call ``accumulate`` after each modality's backward and
    ``step`` once per iteration (after the optimizer steps)."""

    def __init__(self, cfg: DensifyConfig, modalities, scene_extent: float, generator: torch.Generator):
        self.cfg = cfg
        self.modalities = tuple(modalities)
        self.extent = scene_extent
        self.generator = generator
        self.stats = DensifyStats()
        self.growing = True      # cleared by the trainer's automatic budget
        self.resets_done: int | None = None     # opacity resets passed (set at the first step: a resumed run does not reset at once)

    def accumulate(self, modality: str, means2d_grad: torch.Tensor, radii: torch.Tensor,
                   width: int, height: int) -> None:
        """means2d_grad: (N, 2) pixel-space gradient; radii: (N,) of the same render."""
        n = means2d_grad.shape[0]
        if not self.stats.grad or self.stats.grad[self.modalities[0]].shape[0] != n:
            self.stats.reset(n, self.modalities)
        g = means2d_grad * torch.tensor([width / 2.0, height / 2.0])
        vis = radii > 0
        # adding 0 where not drawn: the same sums as masked indexing, without its gathers
        self.stats.grad[modality] += torch.where(vis, g.norm(dim=1), 0.0)
        self.stats.count[modality] += vis

    def mean_grad(self, roles: torch.Tensor | None) -> torch.Tensor:
        """(N,) the densification criterion of each Gaussian given its role."""
        g, c = self.stats.grad, self.stats.count
        pooled = sum(g.values()) / sum(c.values()).clamp_min(1)
        if roles is None or len(self.modalities) < 2:
            return pooled
        own = {m: g[m] / c[m].clamp_min(1) for m in self.modalities}
        out = pooled.clone()
        out[roles == routing.RGB_ONLY] = own["rgb"][roles == routing.RGB_ONLY]
        out[roles == routing.THERMAL_ONLY] = own["thermal"][roles == routing.THERMAL_ONLY]
        return out

    def dead(self, params: nn.ParameterDict, roles: torch.Tensor | None) -> torch.Tensor:
        """(N,) bool: a Gaussian is dead when every modality it takes part in is transparent."""
        thr = self.cfg.prune_opacity
        low = {m: torch.sigmoid(params[f"opacity_{m}"].detach()) < thr for m in self.modalities}
        dead = torch.stack(list(low.values())).all(0)
        if roles is not None:
            dead = torch.where(roles == routing.RGB_ONLY, low["rgb"], dead)
            dead = torch.where(roles == routing.THERMAL_ONLY, low["thermal"], dead)
        bad = ~torch.isfinite(params["means"].detach()).all(1) | ~torch.isfinite(params["log_scales"].detach()).all(1)
        return dead | bad

    @staticmethod
    def _within(candidates: torch.Tensor, grad: torch.Tensor, room: int) -> torch.Tensor:
        """The candidates with the largest gradients that fit in `room` more Gaussians (a split or
        a clone adds one net Gaussian each)."""
        if candidates.sum() <= room:
            return candidates
        top = torch.zeros_like(candidates)
        if room > 0:
            top[torch.where(candidates, grad, -1.0).topk(room).indices] = True
        return candidates & top

    @torch.no_grad()
    def reset_opacities(self, params: nn.ParameterDict, optimizer: torch.optim.Optimizer, progress: float) -> bool:
        """3DGS's opacity reset, once each time progress passes a multiple of opacity_reset_every
        while densifying: every modality's opacity is capped at reset_opacity and its Adam moments
        are cleared. Returns whether it reset."""
        every = self.cfg.opacity_reset_every
        if every <= 0 or not self.cfg.start <= progress < self.cfg.stop:
            return False
        due = int(progress / every)
        if self.resets_done is None:
            self.resets_done = due
        if due <= self.resets_done:
            return False
        self.resets_done = due
        cap = float(torch.logit(torch.tensor(self.cfg.reset_opacity)))
        for m in self.modalities:
            swap_parameter(params, optimizer, f"opacity_{m}", lambda x: x.clamp(max=cap), torch.zeros_like)
        return True

    @torch.no_grad()
    def bound_scales(self, log_scales: torch.Tensor) -> None:
        """In place: log_scales (N, 3) held at most log(max_scale x extent), if bounded."""
        if self.cfg.max_scale > 0:
            log_scales.clamp_(max=math.log(self.cfg.max_scale * self.extent))

    def active(self, iteration: int, progress: float) -> bool:
        return (self.cfg.start <= progress < self.cfg.stop and iteration > 0
                and iteration % self.cfg.every == 0)

    @torch.no_grad()
    def step(self, params: nn.ParameterDict, optimizer: torch.optim.Optimizer,
             iteration: int, progress: float) -> dict[str, int]:
        """Densify and prune if this iteration is a densification step. Returns counts."""
        if not self.active(iteration, progress) or not self.stats.grad:
            return {}
        n = params["means"].shape[0]
        if self.stats.grad[self.modalities[0]].shape[0] != n:
            self.stats.reset(n, self.modalities)
            return {}
        roles = routing.hard_roles(params["route_logits"].detach()) if "route_logits" in params else None
        report = {"cloned": 0, "split": 0, "pruned": 0}
        if self.growing:
            grad = self.mean_grad(roles)
            candidates = grad >= self.cfg.grad_threshold
            # Moving Gaussians have a budget of their own: a moving object is tracked after the
            # static scene has taken the main budget, and must still be able to grow.
            moving = params["motion_basis"].detach() > 0 if "motion_basis" in params else torch.zeros_like(candidates)
            n_moving = int(moving.sum())
            static_room = self.cfg.max_gaussians - (n - n_moving)
            moving_room = int(self.cfg.moving_budget * self.cfg.max_gaussians) - n_moving
            candidates = (self._within(candidates & ~moving, grad, static_room // 2)
                          | self._within(candidates & moving, grad, moving_room))
            big = params["log_scales"].detach().exp().max(1).values > self.cfg.percent_dense * self.extent
            clone, to_split = candidates & ~big, candidates & big
            report["cloned"], report["split"] = int(clone.sum()), int(to_split.sum())
            duplicate(params, optimizer, clone)
            to_split = torch.cat([to_split, torch.zeros(int(clone.sum()), dtype=torch.bool)])
            split(params, optimizer, to_split, self.generator)
            roles = routing.hard_roles(params["route_logits"].detach()) if "route_logits" in params else None
        dead = self.dead(params, roles)
        if self.cfg.prune_scale > 0:
            dead |= params["log_scales"].detach().max(1).values > math.log(self.cfg.prune_scale * self.extent)
        report["pruned"] = int(dead.sum())
        if dead.any() and dead.sum() < dead.numel():
            remove(params, optimizer, dead)
        self.stats.reset(params["means"].shape[0], self.modalities)
        return report
