"""Training losses (DTG paper 3.4; E-D3DGS 2.4).

L = L_rec + lambda_KL KL(mean s_soft || p0) + lambda_embed L_embed + lambda_time L_time, with
RGB L1 + D-SSIM and thermal L1 over valid pixels (count 0 = no measurement).
"""
from __future__ import annotations

import torch

from recon.dtg.neighbours import knn_indices
from recon.eval import ssim


def rgb_loss(pred: torch.Tensor, gt: torch.Tensor, dssim_weight: float) -> torch.Tensor:
    """(1 - l) L1 + l (1 - SSIM), as 3DGS. pred, gt: (H, W, 3) in [0, 1]."""
    l1 = (pred - gt).abs().mean()
    if dssim_weight <= 0:
        return l1
    return (1 - dssim_weight) * l1 + dssim_weight * (1 - ssim(pred, gt))


def thermal_loss(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """L1 of normalised temperature over valid pixels. pred, gt: (H, W); valid: (H, W) bool."""
    count = int(valid.sum())
    if count == 0:
        return pred.sum() * 0
    # a select, not err[valid]: boolean indexing's backward (index_put_) took 5x as long at 160x120
    return torch.where(valid, (pred - gt).abs(), 0.0).sum() / count


def trimmed_l1(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor | None, keep: float) -> torch.Tensor:
    """Mean absolute error over the `keep` fraction of (valid) pixels that fit best: a frame whose
    moving objects the model cannot place yet still teaches the static scene, without those
    objects being painted onto it (RobustNeRF's trimmed estimator). pred, gt: (H, W) or (H, W, C)."""
    err = (pred - gt).abs()
    err = err.mean(-1) if err.dim() == 3 else err
    count = err.numel() if valid is None else int(valid.sum())
    if count == 0:
        return pred.sum() * 0
    # the order statistic below torch.quantile's interpolated value: the same pixels are kept
    # (nothing lies strictly between two neighbouring order statistics), by selection instead of
    # a sort (0.7 against 5.3 ms for 320x240); invalid pixels rank last
    k = int(keep * (count - 1)) + 1
    ranked = err.detach() if valid is None else torch.where(valid, err.detach(), float("inf"))
    limit = ranked.reshape(-1).kthvalue(k).values
    kept = err <= limit if valid is None else valid & (err <= limit)
    # selects, not boolean indexing: its backward (index_put_) was 4x the whole loss at 160x120
    return torch.where(kept, err, 0.0).sum() / kept.sum()


def gather_rows(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """x[index] (index of any shape, rows may repeat) through index_select: the backward of
    advanced indexing (index_put_ with accumulate) sums repeated rows in an order that depends on
    thread timing, so training did not repeat bit for bit; index_add_ sums them in index order."""
    return x.index_select(0, index.reshape(-1)).view(*index.shape, *x.shape[1:])


class EmbeddingSmoothness:
    """E-D3DGS local smoothness: mean over neighbour pairs of sqrt(w) ||e_i - e_j||,
    w = exp(-falloff d^2 / extent^2), neighbours by canonical position.

    The k-NN graph is rebuilt when the Gaussian count changes (densification); each call scores a
    random sample of Gaussians, which keeps the term cheap at any N.
    """

    def __init__(self, k: int, sample: int, falloff: float, extent: float):
        self.k, self.sample, self.falloff, self.extent = k, sample, falloff, extent
        self._n = -1
        self._neighbours: torch.Tensor | None = None

    def state(self) -> dict:
        return {"n": self._n, "neighbours": self._neighbours}

    def load_state(self, state: dict) -> None:
        self._n, self._neighbours = state["n"], state["neighbours"]

    def __call__(self, means: torch.Tensor, embeddings: list[torch.Tensor],
                 generator: torch.Generator) -> torch.Tensor:
        n = means.shape[0]
        if n < 2:
            return means.sum() * 0
        if n != self._n:
            self._neighbours = knn_indices(means.detach(), self.k)
            self._n = n
        idx = torch.randperm(n, generator=generator)[: self.sample]
        # each sampled row and its k neighbours in one gather: the backward then zero-fills one
        # dense (N, D) gradient per embedding, not two (1.5 ms each at 80k Gaussians)
        rows = torch.cat([idx[:, None], self._neighbours[idx]], 1)       # (S, 1 + k)
        fixed = gather_rows(means.detach(), rows)
        d2 = (fixed[:, :1] - fixed[:, 1:]).pow(2).sum(-1)
        w = torch.exp(-self.falloff * d2 / max(self.extent, 1e-9) ** 2)
        total = 0
        for e in embeddings:
            sub = gather_rows(e, rows)
            diff = (sub[:, :1] - sub[:, 1:]).pow(2).sum(-1)
            total = total + torch.sqrt(w * diff + 1e-20).mean()
        return total
