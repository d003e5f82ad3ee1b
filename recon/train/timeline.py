"""Growing a model's time axis while it trains (live capture: recon/live/follow.py): the time
embedding's tables, per-Gaussian trajectory knots and motion-body knots get more rows, and their
Adam moments follow, so training continues without losing what it learned."""
from __future__ import annotations

import torch

from recon.dtg.gaussians import extend_knots
from recon.dtg.model import DTGModel
from recon.dtg.strategy import swap_parameter
from recon.dtg.time_embedding import resample_rows


def extend_time(model: DTGModel, optimizer: torch.optim.Optimizer, factor: int) -> None:
    """Make the time embedding (and trajectories, motion bodies) cover a `factor` times longer span
    without losing what they learned (TimeEmbedding.extended); Adam moments are padded with zeros."""
    def pad(v: torch.Tensor, rows: int) -> torch.Tensor:
        return torch.cat([v, v.new_zeros(rows - v.shape[0], *v.shape[1:])])
    _replace_time_tables(model, optimizer, model.time_embedding.extended(factor), pad)
    knots = lambda x, moment: extend_knots(x, factor, zero=moment)  # noqa: E731
    _resize_trajectories(model, optimizer, knots)
    _resize_motion(model, optimizer, knots)


def refine_time(model: DTGModel, optimizer: torch.optim.Optimizer, factor: int) -> None:
    """`factor` times more time-embedding rows (and knots) over the same span
    (TimeEmbedding.refined); Adam moments are interpolated like the rows."""
    _replace_time_tables(model, optimizer, model.time_embedding.refined(factor), resample_rows)
    refine = lambda x, _: resample_rows(x, (x.shape[1] - 1) * factor + 1, dim=1)  # noqa: E731
    _resize_trajectories(model, optimizer, refine)
    _resize_motion(model, optimizer, refine)


@torch.no_grad()
def _resize_motion(model: DTGModel, optimizer: torch.optim.Optimizer, fn) -> None:
    """fn(knots (B, K, C), is_moment) -> (B, K', C) for the motion bodies, their Adam moments and their
    paths' anchors (is_moment: new knots are zero, not copies: an extended span is not anchored)."""
    motion = model.motion
    if motion is None:
        return
    for name in ("rotation", "translation"):
        old = getattr(motion, name)
        param = torch.nn.Parameter(fn(old.detach(), False).clone())
        group = next(g for g in optimizer.param_groups if g["name"] == f"motion_{name}")
        group["params"] = [param]
        state = optimizer.state.pop(old, {})
        if state:
            optimizer.state[param] = {k: (fn(v, True) if torch.is_tensor(v) and v.dim() == 3 else v)
                                      for k, v in state.items()}
        setattr(motion, name, param)
    # the paths' anchors follow their knots; a new knot is anchored only between anchored ones
    anchored = fn(motion.anchored[..., None].float(), True)[..., 0]
    motion.anchors, motion.anchored = fn(motion.anchors, True), anchored >= 1 - 1e-6
    b, k = motion.anchor_precision.shape[:2]
    precision = fn(motion.anchor_precision.reshape(b, k, 9), True)
    motion.anchor_precision = precision.reshape(b, precision.shape[1], 3, 3)


def _resize_trajectories(model: DTGModel, optimizer: torch.optim.Optimizer, fn) -> None:
    """fn(knots (N, K, 3), is_moment) -> (N, K', 3) for the trajectory and its Adam moments."""
    if "trajectory" in model.gaussians:
        swap_parameter(model.gaussians, optimizer, "trajectory", lambda x: fn(x, False), lambda x: fn(x, True))


@torch.no_grad()
def _replace_time_tables(model: DTGModel, optimizer: torch.optim.Optimizer, new: dict[str, torch.Tensor],
                         moments) -> None:
    """Install new time-embedding tables as fresh parameters of the optimizer;
    moments(old (R, D) Adam moment, new row count) -> its (R', D) successor."""
    te = model.time_embedding
    group = next(g for g in optimizer.param_groups if g["name"] == "time_embedding")
    for name, table in new.items():
        old = getattr(te, name)
        param = torch.nn.Parameter(table.clone())
        state = optimizer.state.pop(old, {})
        group["params"] = [param if p is old else p for p in group["params"]]
        if state:
            optimizer.state[param] = {k: (moments(v, table.shape[0]) if torch.is_tensor(v) and v.dim() == 2 else v)
                                      for k, v in state.items()}
        setattr(te, name, param)
