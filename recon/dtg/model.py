"""Dynamic Thermal Gaussians: canonical Gaussians + time embedding + deformation + routing.

``render_inputs(modality, t)`` gives what the rasterizer needs for one modality at time t:

- deformation "none": the canonical Gaussians (static-rgbt).
- "shared": one network F(e_t, e_i) moves the shared geometry and changes every modality's
  opacity and features (E-D3DGS; "+ shared Gaussian").
- "progressive" (DTG): F_rgb(e_t, e_i^rgb) -> (dmu, dr, ds, dsigma_rgb, df_rgb), then
  F_th(e_t, e_i^th) -> (dmu, dr, ds, dsigma_th, df_th) on the geometry the first stage produced.
  Residuals are added to raw parameters, before activations (E-D3DGS).

Routing masks multiply the activated opacity of their modality.
"""
from __future__ import annotations

import torch
from torch import nn

from recon.config import ModelConfig
from recon.dtg.deformation import DeformationNet, geometry_outputs, modality_outputs
from recon.dtg.gaussians import embedding_key, embedding_keys, sh_coeffs
from recon.dtg.motion import MotionBases, apply_motion
from recon.dtg.time_embedding import TimeEmbedding, lerp_rows

GEOMETRY = ("means", "quats", "log_scales")
NOT_LEARNED = ("dynamic", "motion_basis", "in_place")      # per-Gaussian state the trainer sets (densification still carries it)


def added(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """a + b for dicts of tensors where a missing key stands for zero (residual dicts hold only what
    something moves: no full-size zeros, ~1 ms at 80k Gaussians); a's keys first."""
    out = dict(a)
    for k, v in b.items():
        out[k] = out[k] + v if k in out else v
    return out


def feature_shape(cfg: ModelConfig, modality: str) -> tuple[int, int]:
    """(K, C) of a modality's SH features."""
    if modality == "rgb":
        return sh_coeffs(cfg.rgb_sh_degree), 3
    return sh_coeffs(cfg.thermal_sh_degree), 1


def time_rows(cfg: ModelConfig, n_times: int) -> tuple[int, int]:
    coarse = cfg.time_rows_coarse or max(4, round(n_times / 10))
    fine = cfg.time_rows_fine or max(2, round(max(n_times, 16) / cfg.steps_per_fine_row))
    return coarse, fine


class DTGModel(nn.Module):
    def __init__(self, cfg: ModelConfig, params: dict[str, torch.Tensor], n_times: int,
                 backgrounds: dict[str, torch.Tensor] | None = None, pivots: torch.Tensor | None = None,
                 radii: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg
        self.n_times = n_times
        self.gaussians = nn.ParameterDict({k: nn.Parameter(v, requires_grad=k not in NOT_LEARNED)
                                           for k, v in params.items()})
        bg = backgrounds or {}
        self.backgrounds = nn.ParameterDict({
            m: nn.Parameter(bg.get(m, torch.zeros(feature_shape(cfg, m)[1]))) for m in cfg.modalities})
        self.deformers = nn.ModuleDict()
        self.motion = None
        if cfg.motion_bases and cfg.deformation != "none":
            self.motion = MotionBases(pivots if pivots is not None else torch.zeros(0, 3), n_times, radii)
        if cfg.deformation != "none":
            coarse, fine = time_rows(cfg, n_times)
            self.time_embedding = TimeEmbedding(cfg.time_embedding_dim, coarse, fine,
                                                cfg.time_rows_fine_start, cfg.time_c2f_until)
            stages = ["shared"] if cfg.deformation == "shared" else list(cfg.modalities)
            for stage in stages:
                outs = geometry_outputs() if stage == "shared" or stage in cfg.deform_geometry else {}
                for m in (cfg.modalities if stage == "shared" else [stage]):
                    k, c = feature_shape(cfg, m)
                    outs.update(modality_outputs(m, k * c, m in cfg.deform_opacity, m in cfg.deform_features))
                if not outs:     # nothing to predict (e.g. F_rgb when motion bases move geometry)
                    continue
                self.deformers[stage] = DeformationNet(cfg.time_embedding_dim, cfg.gaussian_embedding_dim,
                                                       cfg.mlp_width, outs, cfg.geometry_bias)

    @property
    def num_gaussians(self) -> int:
        return self.gaussians["means"].shape[0]

    def stage_residuals(self, stage: str, t: float, progress: float,
                        rows: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Residuals (N, size) of one deformation stage ('shared', 'rgb' or 'thermal') at time t.
        rows (R,): only these Gaussians' are computed, the others' are zero."""
        if stage not in self.deformers:
            return {}
        key = embedding_key(stage)
        e_t = self.time_embedding(t, progress)
        if rows is None:
            return self.deformers[stage](e_t, self.gaussians[key])
        part = self.deformers[stage](e_t, self.gaussians[key].index_select(0, rows))
        n = self.num_gaussians
        return {k: v.new_zeros(n, v.shape[1]).index_copy(0, rows, v) for k, v in part.items()}

    def moves_geometry(self, stage: str) -> bool:
        """Whether a stage's network predicts geometry residuals (then every Gaussian's are needed
        to know where it is)."""
        return stage in self.deformers and any(k in self.deformers[stage].outputs for k in GEOMETRY)

    def body_geometry_gate(self, stage: str) -> torch.Tensor | None:
        """(N,) what a stage's geometry residuals are multiplied by when only the bodies' Gaussians
        may take them (ModelConfig.geometry_on_bodies): each body member's dynamic gate, 0 for
        static Gaussians; None when every Gaussian takes them."""
        if not (self.cfg.geometry_on_bodies and self.motion is not None and self.moves_geometry(stage)):
            return None
        return self.dynamic_gate() * (self.gaussians["motion_basis"] > 0)

    def geometry_gate(self, stage: str, progress: float = 1.0) -> torch.Tensor | None:
        """(N,) what a stage's network geometry residuals are multiplied by: the bodies' gate
        (``body_geometry_gate``) times each Gaussian's learned gate sigmoid(geometry_logit)
        (ModelConfig.geometry_gate_init, priced by PriorConfig.geometry_gate), zero for the Gaussians
        held in place (ModelConfig.hold_in_place) and, before ModelConfig.geometry_from, for those
        outside bodies; None for none of these."""
        gate = self.body_geometry_gate(stage)
        if "geometry_logit" in self.gaussians and self.moves_geometry(stage):
            learned = torch.sigmoid(self.gaussians["geometry_logit"])
            gate = learned if gate is None else gate * learned
        if "in_place" in self.gaussians and self.moves_geometry(stage):
            free = 1 - self.gaussians["in_place"]
            gate = free if gate is None else gate * free
        if progress < self.cfg.geometry_from and "motion_basis" in self.gaussians and self.moves_geometry(stage):
            bodies = (self.gaussians["motion_basis"] > 0).float()     # the rest wait (geometry_on)
            gate = bodies if gate is None else gate * bodies
        return gate

    def motion_stage(self) -> str | None:
        """The deformation stage whose geometry every modality's render builds on ('shared',
        'rgb' or 'thermal'), or None for a static model: where the motion priors apply."""
        cfg = self.cfg
        if cfg.deformation == "none":
            return None
        if cfg.deformation == "shared":
            return "shared"
        return next((m for m in cfg.modalities if m in cfg.deform_geometry), None)

    def stage_of(self, modality: str) -> str | None:
        """The deformation stage that renders a modality."""
        if self.cfg.deformation == "none":
            return None
        return "shared" if self.cfg.deformation == "shared" else modality

    def means_at(self, stage: str, t: float, progress: float, index: torch.Tensor) -> torch.Tensor:
        """Positions (S, 3) at time t of the Gaussians `index` (S,) after one stage's residuals."""
        if stage is None or stage not in self.deformers or not self.geometry_on(progress):
            moved = torch.zeros_like(self.gaussians["means"][index])    # no network moves geometry (bases may)
        else:
            key = embedding_key(stage)
            res = self.deformers[stage](self.time_embedding(t, progress), self.gaussians[key][index])
            moved = res["means"]
            gate = self.geometry_gate(stage, progress)
            if gate is not None:
                moved = moved * gate[index, None]
        if "trajectory" in self.gaussians:
            moved = moved + lerp_rows(self.gaussians["trajectory"][index], t, dim=1)
        if "dynamic_logit" in self.gaussians and self.motion is None:
            moved = moved * self.dynamic_gate(index)[:, None]
        if "dynamic" in self.gaussians:
            moved = moved * self.gaussians["dynamic"][index, None]
        means = self.gaussians["means"][index] + moved
        if self.motion is not None:
            means, _ = apply_motion(means, None, self.gaussians["motion_basis"][index],
                                    self.dynamic_gate(index), self.motion, t)
        return means

    def geometry_on(self, progress: float) -> bool:
        """Whether the networks' geometry residuals apply at this progress (ModelConfig.geometry_from):
        with bodies always, their members' from the start and the others' from geometry_from
        (geometry_gate)."""
        return progress >= self.cfg.geometry_from or "motion_basis" in self.gaussians

    def dynamic_gate(self, index: torch.Tensor | slice = slice(None)) -> torch.Tensor:
        """(N,) or (S,) how much each Gaussian may move (needs a static/dynamic split)."""
        return torch.sigmoid(self.gaussians["dynamic_logit"][index])

    def render_inputs(self, modality: str, t: float, progress: float = 1.0,
                      mask: torch.Tensor | None = None,
                      rgb_geometry: dict[str, torch.Tensor] | None = None,
                      in_view=None) -> dict[str, torch.Tensor]:
        """Gaussians of one modality at time t.

        mask: (N,) routing mask for this modality or None. rgb_geometry: first-stage geometry
        residuals to reuse for the thermal stage (the RGB stage of the same iteration computed them).
        in_view: geometry {means, quats, log_scales} -> (R,) indices of the Gaussians a render can
        show, or None. When this modality's network changes only opacity and features, it runs on
        those rows alone (the others get no residual: they are not drawn).
        Returns means (N,3), quats (N,4), log_scales (N,3), opacities (N,), features (N,K,C), and
        ``geometry_residuals`` (the residuals this call applied, for reuse).
        """
        g = self.gaussians
        cfg = self.cfg
        geo = {k: g[k] for k in GEOMETRY}
        opacity_logit = g[f"opacity_{modality}"]
        features = g[f"features_{modality}"]
        if f"features_{modality}_rest" in g:
            features = torch.cat([features, g[f"features_{modality}_rest"]], dim=1)
        applied: dict[str, torch.Tensor] = {}
        if cfg.deformation != "none":
            stage = "shared" if cfg.deformation == "shared" else modality
            # a network that changes only opacity and features runs after the geometry, on the rows in view
            later = in_view is not None and stage in self.deformers and not self.moves_geometry(stage)
            first = None
            if cfg.deformation == "progressive" and modality == "thermal" and "rgb" in cfg.modalities:
                first = rgb_geometry
                if first is None and (not self.moves_geometry("rgb") or not self.geometry_on(progress)):
                    first = {}         # F_rgb moves no geometry (yet): nothing to add
                if first is None:      # what the RGB stage's render applied (its gates too)
                    rgb_gate = self.geometry_gate("rgb", progress)
                    first = {k: v if rgb_gate is None else v * rgb_gate[:, None]
                             for k, v in self.stage_residuals("rgb", t, progress).items() if k in GEOMETRY}
                if not cfg.thermal_grad_to_rgb_deformation:
                    first = {k: v.detach() for k, v in first.items()}

            def place(own: dict[str, torch.Tensor]):
                """This stage's geometry residuals (after its gate) -> (geometry, residuals applied).
                A stage without a network that moves geometry (dtg's RGB stage) has none (`added`)."""
                applied = added(own, first or {})
                if "trajectory" in g:       # shared by every modality, trained by every loss
                    applied = added(applied, {"means": lerp_rows(g["trajectory"], t, dim=1)})
                if "dynamic_logit" in g and self.motion is None:
                    gate = self.dynamic_gate()[:, None]
                    applied = {k: v * gate for k, v in applied.items()}
                if "dynamic" in g:
                    applied = {k: v * g["dynamic"][:, None] for k, v in applied.items()}
                moved = added(geo, applied)
                if self.motion is not None:
                    moved["means"], moved["quats"] = apply_motion(moved["means"], moved["quats"], g["motion_basis"],
                                                                  self.dynamic_gate(), self.motion, t)
                return moved, applied

            body_gate = self.body_geometry_gate(stage)
            rows = None
            if body_gate is not None and in_view is not None and "trajectory" not in g:
                # only bodies move: the static rows in view are known before the network runs
                canonical = in_view({k: v.detach() for k, v in geo.items()})
                rows = torch.unique(torch.cat([canonical, torch.nonzero(body_gate).view(-1)]))
            elif in_view is not None and not later and cfg.view_margin is not None and stage in self.deformers:
                # the rows whose place before this network is in the view or window, widened
                with torch.no_grad():
                    before = place({})[0]
                rows = in_view(before, margin=cfg.view_margin)
            # a Gaussian the routing has removed from this modality for good (a fixed mask's zero: not
            # drawn, no gradient) needs no residuals, unless another stage reuses this one's geometry
            routed = None
            if (mask is not None and not mask.requires_grad and stage in self.deformers
                    and not (cfg.deformation == "progressive" and modality == "rgb" and self.moves_geometry("rgb"))):
                routed = mask > 0

            def drawn(rows: torch.Tensor | None) -> torch.Tensor | None:
                if routed is None:
                    return rows
                return torch.nonzero(routed).view(-1) if rows is None else rows[routed.index_select(0, rows)]
            res = {} if later else self.stage_residuals(stage, t, progress, rows=drawn(rows))
            own = {k: res[k] for k in GEOMETRY if k in res} if self.geometry_on(progress) else {}
            gate = self.geometry_gate(stage, progress)
            if gate is not None:
                own = {k: v * gate[:, None] for k, v in own.items()}
            geo, applied = place(own)
            if later:
                rows = drawn(in_view({k: v.detach() for k, v in geo.items()}))
                res = self.stage_residuals(stage, t, progress, rows=rows)
            if f"opacity_{modality}" in res:
                opacity_logit = opacity_logit + res[f"opacity_{modality}"][:, 0]
            if f"features_{modality}" in res:
                features = features + res[f"features_{modality}"].view_as(features)
        opacities = torch.sigmoid(opacity_logit)
        if mask is not None:
            opacities = opacities * mask
        return {**geo, "opacities": opacities, "features": features, "geometry_residuals": applied}

    def state_for_checkpoint(self) -> dict:
        return {"state_dict": self.state_dict(), "n_times": self.n_times}

    @classmethod
    def from_checkpoint(cls, cfg: ModelConfig, state: dict) -> "DTGModel":
        sd = state["state_dict"]
        params = {k[len("gaussians."):]: v.clone() for k, v in sd.items() if k.startswith("gaussians.")}
        model = cls(cfg, params, state["n_times"], pivots=sd.get("motion.pivots"), radii=sd.get("motion.radii"))
        if model.motion is not None:        # a live run may have extended the knots
            for name in ("rotation", "translation"):
                setattr(model.motion, name, nn.Parameter(sd[f"motion.{name}"].clone()))
        for name in ("coarse", "fine"):     # a live run may have extended or refined them
            key = f"time_embedding.{name}"
            if key in sd:
                setattr(model.time_embedding, name, nn.Parameter(sd[key].clone()))
        if model.motion is not None and "motion.radii" not in sd:     # written before bodies had a reach
            sd = {**sd, "motion.radii": torch.zeros(model.motion.count)}
        if model.motion is not None and "motion.anchored" not in sd:  # written before paths were anchored
            sd = {**sd, "motion.anchors": torch.zeros_like(model.motion.translation),
                  "motion.anchored": torch.zeros(model.motion.translation.shape[:2], dtype=torch.bool)}
        if model.motion is not None and "motion.anchor_precision" not in sd:  # written before paths had a covariance
            sd = {**sd, "motion.anchor_precision": torch.zeros(*model.motion.translation.shape[:2], 3, 3)}
        if model.motion is not None:        # as many knots as the translation's
            model.motion.anchors, model.motion.anchored = sd["motion.anchors"].clone(), sd["motion.anchored"].clone()
            model.motion.anchor_precision = sd["motion.anchor_precision"].clone()
        model.load_state_dict(sd)
        return model


def check_params(cfg: ModelConfig, params: dict[str, torch.Tensor]) -> None:
    """Every expected per-Gaussian tensor is present with one row per Gaussian."""
    expected = list(GEOMETRY) + [f"{p}_{m}" for m in cfg.modalities for p in ("features", "opacity")]
    expected += embedding_keys(cfg) + (["route_logits"] if cfg.routing else [])
    expected += ["trajectory"] if cfg.trajectory_step and cfg.deformation != "none" else []
    expected += ["dynamic_logit"] if (cfg.dynamic_gate or cfg.motion_bases) and cfg.deformation != "none" else []
    expected += ["motion_basis"] if cfg.motion_bases and cfg.deformation != "none" else []
    expected += ["geometry_logit"] if cfg.geometry_gate_init is not None and cfg.deformation != "none" else []
    expected += ["dynamic"] if cfg.motion_split and cfg.deformation != "none" else []
    expected += ["in_place"] if cfg.hold_in_place and cfg.deformation != "none" else []
    n = params["means"].shape[0]
    for key in expected:
        if key not in params:
            raise ValueError(f"Gaussian parameter {key!r} missing")
        if params[key].shape[0] != n:
            raise ValueError(f"Gaussian parameter {key!r} has {params[key].shape[0]} rows, expected {n}")
