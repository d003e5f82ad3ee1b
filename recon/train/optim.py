"""The optimizer of a run: one Adam group per per-Gaussian tensor and per network, and the
learning-rate schedule as a function of progress p (3DGS-style log-linear decay)."""
from __future__ import annotations

import math

import torch

from recon.config import TrainConfig
from recon.dtg.model import DTGModel


def log_lerp(a: float, b: float, p: float) -> float:
    """Exponential (log-linear) decay from a to b as p goes 0 -> 1 (3DGS get_expon_lr_func)."""
    p = min(max(p, 0.0), 1.0)
    return math.exp(math.log(a) * (1 - p) + math.log(b) * p)


def base_lr(cfg: TrainConfig, key: str, extent: float) -> float:
    """Starting learning rate of the per-Gaussian tensor `key`."""
    lr = cfg.lr
    if key == "means":
        return lr.means_scene[0] * extent
    if key.startswith("features_"):
        if key.endswith("_rest"):
            return lr.rgb_rest if "rgb" in key else lr.thermal / 20
        return lr.rgb_dc if "rgb" in key else lr.thermal
    if key == "trajectory":
        return lr.trajectory_scene[0] * extent
    if key in ("dynamic_logit", "geometry_logit"):
        return lr.dynamic
    table = {"quats": lr.quats, "log_scales": lr.scales, "route_logits": cfg.routing.lr}
    if key in table:
        return table[key]
    if key.startswith("opacity_"):
        return lr.opacity
    if key.startswith("embedding"):
        return lr.embedding
    raise KeyError(f"no learning rate for Gaussian parameter {key!r}")


def build_optimizer(cfg: TrainConfig, model: DTGModel, extent: float) -> torch.optim.Optimizer:
    """Adam over every learned tensor of the model, one named group each (densification swaps
    per-Gaussian tensors by group name: recon/dtg/strategy.py)."""
    groups = [{"params": [p], "name": k, "lr": base_lr(cfg, k, extent), "base_lr": base_lr(cfg, k, extent)}
              for k, p in model.gaussians.items() if p.requires_grad]
    if cfg.model.deformation != "none":
        groups.append({"params": list(model.deformers.parameters()), "name": "deformation",
                       "lr": cfg.lr.deformation_scene[0] * extent})
        groups.append({"params": list(model.time_embedding.parameters()), "name": "time_embedding",
                       "lr": cfg.lr.time_embedding[0]})
    if model.motion is not None:
        groups.append({"params": [model.motion.rotation], "name": "motion_rotation",
                       "lr": cfg.lr.motion_rotation[0]})
        groups.append({"params": [model.motion.translation], "name": "motion_translation",
                       "lr": cfg.lr.motion_translation_scene[0] * extent})
    groups.append({"params": list(model.backgrounds.parameters()), "name": "backgrounds",
                   "lr": cfg.lr.thermal_background, "base_lr": cfg.lr.thermal_background})
    return LeanAdam(groups, lr=0.0, eps=1e-15, fused=True)


class LeanAdam(torch.optim.Adam):
    """torch's fused Adam (the same kernel, the same state, so checkpoints and densification's
    state swaps are unchanged) without torch.optim's per-step bookkeeping: a DTG step has ~16
    groups of one tensor each, and Adam.step spent 0.85 ms a call at 160x120 / 9k Gaussians, most of
    it in Python, against ~0.3 ms here. Groups of the same rate share one kernel call."""

    @torch.no_grad()
    def step(self, closure=None):
        assert closure is None, "LeanAdam takes no closure"
        calls: dict[tuple, list[list]] = {}
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            key = (group["lr"], beta1, beta2, group["eps"], group["weight_decay"])
            lists = calls.setdefault(key, [[], [], [], [], []])
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["step"] = torch.zeros((), dtype=torch.float32)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                for out, value in zip(lists, (p, p.grad, state["exp_avg"], state["exp_avg_sq"], state["step"])):
                    out.append(value)
        for (lr, beta1, beta2, eps, weight_decay), (params, grads, m, v, steps) in calls.items():
            if not params:
                continue
            torch._foreach_add_(steps, 1)
            torch._fused_adam_(params, grads, m, v, [], steps, amsgrad=False, lr=lr, beta1=beta1, beta2=beta2,
                               weight_decay=weight_decay, eps=eps, maximize=False)

    def zero_grad(self, set_to_none: bool = True) -> None:
        assert set_to_none, "LeanAdam only drops gradients"
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None


def update_learning_rates(optimizer: torch.optim.Optimizer, cfg: TrainConfig, p: float, iteration: int,
                          expected_iterations: float, extent: float, scale: float = 1.0) -> None:
    """Set every group's rate for progress p. expected_iterations: the run's length (routing's rate
    is scaled up for short runs, and the deformation warm-up takes at most a tenth of it);
    scale: lowered by each rollback (recon/train/guard.py)."""
    lr = cfg.lr
    routing_scale = max(1.0, cfg.routing.lr_reference_iterations / max(expected_iterations, 1.0))
    ramp = min(lr.deformation_warmup, 0.1 * expected_iterations)
    warm = min(1.0, (iteration + 1) / ramp) if ramp >= 1 else 1.0
    decayed = {"means": log_lerp(*lr.means_scene, p) * extent,
               "trajectory": log_lerp(*lr.trajectory_scene, p) * extent,
               "deformation": log_lerp(*lr.deformation_scene, p) * extent * warm,
               "motion_rotation": log_lerp(*lr.motion_rotation, p),
               "motion_translation": log_lerp(*lr.motion_translation_scene, p) * extent,
               "time_embedding": log_lerp(*lr.time_embedding, p) * warm,
               "route_logits": cfg.routing.lr * routing_scale}
    for group in optimizer.param_groups:
        group["lr"] = decayed.get(group["name"], group.get("base_lr")) * scale
