"""The per-Gaussian parameters of a DTG model: one dict of (N, ...) tensors.

Shared canonical geometry (``means``, ``quats`` wxyz, ``log_scales``) and, per trained modality m,
SH features: the DC ``features_m`` (N, 1, C_m) and, above degree 0, ``features_m_rest``
(N, K_m - 1, C_m), kept apart because they learn at different rates (3DGS) (RGB: C=3; thermal:
C=1, normalised temperature),
an opacity logit ``opacity_m`` (N,), and the deformation embedding(s); routing logits
``route_logits`` (N, 3) when routing is on; per-Gaussian trajectory knots ``trajectory``
(N, K, 3) when ``trajectory_step`` is set; the static/dynamic gate logit ``dynamic_logit`` (N,)
with ``dynamic_gate``; the static/dynamic flag ``dynamic`` (N,) with ``motion_split`` (not learned);
the gate logit ``geometry_logit`` (N,) on the networks' geometry residuals with ``geometry_gate_init``.

Everything that has one row per Gaussian lives in this dict, so densification and pruning
(recon.dtg.strategy) handle a new attribute without any change.
"""
from __future__ import annotations

import math

import torch

from recon.config import ModelConfig, RoutingConfig
from recon.dtg.neighbours import knn_mean_sq_dist

SH_C0 = 0.28209479177387814


def sh_coeffs(degree: int) -> int:
    return (degree + 1) ** 2


def value_to_sh_dc(value: torch.Tensor) -> torch.Tensor:
    """Inverse of the rasterizer's colour = C0 * dc + 0.5 (degree 0)."""
    return (value - 0.5) / SH_C0


def sh_dc_to_value(dc: torch.Tensor) -> torch.Tensor:
    """The rasterizer's degree-0 colour, C0 * dc + 0.5 (before its clamp at 0)."""
    return SH_C0 * dc + 0.5


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """(N, 4) wxyz quaternions of any non-zero norm -> (N, 3, 3) rotation matrices."""
    q = q / q.norm(dim=1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).view(-1, 3, 3)


def embedding_key(stage: str) -> str:
    """The per-Gaussian tensor a deformation stage ('shared', 'rgb' or 'thermal') reads."""
    return "embedding" if stage == "shared" else f"embedding_{stage}"


def embedding_keys(cfg: ModelConfig) -> list[str]:
    if cfg.deformation == "shared":
        return [embedding_key("shared")]
    if cfg.deformation == "progressive":     # a stage with nothing to predict has no network
        return [embedding_key(m) for m in cfg.modalities
                if m in cfg.deform_geometry or m in cfg.deform_opacity or m in cfg.deform_features]
    return []


def trajectory_knots(cfg: ModelConfig, n_times: int) -> int:
    """Knots of the per-Gaussian trajectories over [0, 1] (0: none): one per trajectory_step time
    steps, at least 2."""
    if not cfg.trajectory_step or cfg.deformation == "none":
        return 0
    return max(2, -(-(n_times - 1) // cfg.trajectory_step) + 1)


def extend_knots(knots: torch.Tensor, factor: int, zero: bool = False) -> torch.Tensor:
    """Knots for a `factor` times longer span at the same spacing: old knots kept, new ones copy
    the last (or are zero, for optimizer moments). (N, K, C) -> (N, f(K-1)+1, C)"""
    extra = (factor - 1) * (knots.shape[1] - 1)
    tail = knots.new_zeros(knots.shape[0], extra, knots.shape[2]) if zero else knots[:, -1:].expand(-1, extra, -1)
    return torch.cat([knots, tail], dim=1)


def init_gaussians(points: torch.Tensor, colors: torch.Tensor, temperatures: torch.Tensor | None,
                   cfg: ModelConfig, routing: RoutingConfig, generator: torch.Generator,
                   knots: int = 0, dynamic: torch.Tensor | None = None,
                   basis: torch.Tensor | None = None, gates: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Gaussians at initial points, 3DGS style.

    points: (M, 3); colors: (M, 3) in [0, 1]; temperatures: (M,) normalised temperature or None;
    dynamic: (M,) bool, which points may move (ModelConfig.motion_split; None: all); gates: (M,)
    starting gate logits of body members (None: ModelConfig.basis_gate_init).
    Scales are isotropic, sqrt of the mean squared distance to the 3 nearest neighbours.
    """
    m = points.shape[0]
    d2 = knn_mean_sq_dist(points).clamp_min(1e-10)
    params = {
        "means": points.clone().float(),
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(m, 1),
        "log_scales": torch.log(d2.sqrt()).unsqueeze(1).repeat(1, 3).float(),
    }
    logit = math.log(cfg.init_opacity / (1 - cfg.init_opacity))
    values = {"rgb": colors.float(),
              "thermal": (temperatures if temperatures is not None else torch.full((m,), 0.5)).float().view(m, 1)}
    degrees = {"rgb": cfg.rgb_sh_degree, "thermal": cfg.thermal_sh_degree}
    for mod in cfg.modalities:
        channels = values[mod].shape[1]
        params[f"features_{mod}"] = value_to_sh_dc(values[mod]).view(m, 1, channels)
        if degrees[mod] > 0:
            params[f"features_{mod}_rest"] = torch.zeros(m, sh_coeffs(degrees[mod]) - 1, channels)
        params[f"opacity_{mod}"] = torch.full((m,), logit)
    for key in embedding_keys(cfg):
        params[key] = torch.randn(m, cfg.gaussian_embedding_dim, generator=generator) * cfg.init_embedding_std
    if cfg.routing:
        params["route_logits"] = torch.log(torch.tensor(routing.prior_before)).repeat(m, 1)
    if knots:
        params["trajectory"] = torch.zeros(m, knots, 3)
    if cfg.dynamic_gate and cfg.deformation != "none" and not cfg.motion_bases:
        params["dynamic_logit"] = torch.full((m,), cfg.init_dynamic)
    if cfg.motion_bases and cfg.deformation != "none":
        params["motion_basis"] = (basis if basis is not None else torch.zeros(m)).float()
        params["dynamic_logit"] = torch.full((m,), cfg.basis_gate_init) if gates is None else gates.float().clone()
    if cfg.geometry_gate_init is not None and cfg.deformation != "none":
        params["geometry_logit"] = torch.full((m,), float(cfg.geometry_gate_init))
    if cfg.hold_in_place and cfg.deformation != "none":
        params["in_place"] = torch.zeros(m)     # 1: held in place (set by the trainer)
    if cfg.motion_split and cfg.deformation != "none":
        params["dynamic"] = (dynamic if dynamic is not None else torch.ones(m)).float()   # 1: may move
    return params
