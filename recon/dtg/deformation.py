"""Embedding-based deformation (E-D3DGS; DTG paper 3.3).

F(e_t, e_i) -> named residuals, one row per Gaussian. The network sees no position or time
coordinate, only the time embedding e_t (D_t,) shared by all Gaussians at one instant and the
per-Gaussian embedding e_i (N, D_e). Its first layer is linear, so W [e_t; e_i] = W_t e_t + W_e e_i:
the time part is computed once per time step, not once per Gaussian.

Trunk: that first layer, then ReLU -> Linear(W, W) -> ReLU -> one Linear to all residuals. E-D3DGS
gives each residual its own two-layer head; one shared hidden layer costs a fifth of that on a CPU,
and the output layer starts at zero so training starts from the canonical (static) model.
"""
from __future__ import annotations

import torch
from torch import nn


class DeformationNet(nn.Module):
    def __init__(self, time_dim: int, embedding_dim: int, width: int, outputs: dict[str, int],
                 geometry_bias: bool = False):
        super().__init__()
        self.outputs = dict(outputs)
        self.time_in = nn.Linear(time_dim, width)
        self.embedding_in = nn.Linear(embedding_dim, width, bias=False)
        self.hidden = nn.Linear(width, width)
        self.out = nn.Linear(width, sum(self.outputs.values()))
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        # No bias on geometry residuals: a bias moves every Gaussian alike (a global shift no
        # static background wants), and Adam moves it by ~lr per step whatever its gradient.
        sizes = list(self.outputs.values())
        mask = torch.cat([torch.full((n,), float(geometry_bias or name not in GEOMETRY_OUTPUTS))
                          for name, n in self.outputs.items()])
        self.register_buffer("bias_mask", mask, persistent=False)
        self._sizes = sizes

    def forward(self, e_t: torch.Tensor, embeddings: torch.Tensor) -> dict[str, torch.Tensor]:
        """e_t: (D_t,); embeddings: (N, D_e) -> {name: (N, size)}"""
        # the time part as the bias of the embedding part's matmul (one addmm, no (N, W) add);
        # ReLUs in place on outputs no backward needs
        h = nn.functional.linear(embeddings, self.embedding_in.weight, self.time_in(e_t)).relu_()
        h = self.hidden(h).relu_()
        out = nn.functional.linear(h, self.out.weight, self.out.bias * self.bias_mask)
        return dict(zip(self.outputs, torch.split(out, self._sizes, dim=1)))


GEOMETRY_OUTPUTS = {"means": 3, "quats": 4, "log_scales": 3}


def geometry_outputs() -> dict[str, int]:
    return dict(GEOMETRY_OUTPUTS)


def modality_outputs(modality: str, feature_size: int, opacity: bool, features: bool) -> dict[str, int]:
    """Residuals of one modality's opacity logit (1) and features (flattened SH), where enabled."""
    out = {f"opacity_{modality}": 1} if opacity else {}
    if features:
        out[f"features_{modality}"] = feature_size
    return out
