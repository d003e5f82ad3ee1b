"""Motion priors: what makes moving things move as near-rigid bodies along smooth paths.

With one RGB and one thermal view per instant, a deformation field can fit every training view
with motion that is wrong from anywhere else (a ball slid along the training camera's rays,
smeared, or painted onto the floor). These terms, each a config switch (``PriorConfig``), pull
the deformation towards physically plausible motion:

- local rigidity (Dynamic 3D Gaussians, Luiten et al. 2024): a Gaussian's canonical neighbours
  keep their offsets in its rotating frame, ``|| (mu_j(t) - mu_i(t)) - dR_i(t) (mu_j - mu_i) ||``;
- isometry: neighbour distances are kept, ``| ||mu_j(t) - mu_i(t)|| - ||mu_j - mu_i|| |``;
- rotation similarity: neighbours rotate alike, ``|| dR_i(t) - dR_j(t) ||``;
- trajectory smoothness: small acceleration ``mu(t - dt) - 2 mu(t) + mu(t + dt)`` over one time
  step (the geometry at t +- dt is evaluated for the sampled Gaussians only);
- motion sparsity: a small L1 price on displacement, so the static background cannot absorb
  motion that belongs to objects (a static/dynamic split without a hard label);
- residual sparsity: the same L1 price on a network's geometry residuals only (not on the rigid
  bodies' motion): with bodies, F_th may move any Gaussian in the thermal render, and without a
  price the whole static scene can slide where the thermal frames do not pin it;
- one temperature per body: a rigid body's members (motion_basis > 0, gate open) whose thermal
  colour lies more than a band beyond their body's median pay for the excess (``body_warmth``).
  A sphere of Gaussians built on a can is wider than the can in places; fitted to the training
  views, those parts turned the background's temperature instead of transparent, and from the
  held-out rig they cover the can with cold patches (family-outside 45: 5 % of the can's body
  weight at ~296 K, the can 22 K off);
- anisotropy (a shape prior, PhysGaussian's): Gaussians longer than ``max_aspect`` times their
  width pay for it. Needles and sheets that fit the training sweep look like streaks from 17-45
  degrees beyond it.

Neighbours are the k nearest in canonical space, weighted by exp(-falloff d^2 / E^2) (E: scene
extent), so a ball's Gaussians are held together while the floor under it barely pulls.
Distances are in units of E, so weights do not depend on the scene's scale. Each call scores a
random sample of Gaussians: the cost does not grow with N.
"""
from __future__ import annotations

import torch

from recon.config import PriorConfig
from recon.dtg.gaussians import quat_to_rotmat
from recon.dtg.losses import gather_rows
from recon.dtg.neighbours import knn_indices


def rigidity_terms(means_c: torch.Tensor, quats_c: torch.Tensor, means_t: torch.Tensor,
                   quats_t: torch.Tensor, idx: torch.Tensor, nb: torch.Tensor, weights: torch.Tensor,
                   extent: float) -> dict[str, torch.Tensor]:
    """Local rigidity, isometry and rotation similarity of Gaussians idx (S,) to their
    neighbours nb (S, k) with weights (S, k), between canonical (c) and deformed (t) geometry
    (means (N, 3), quats (N, 4)). Canonical values act as the reference (no gradient)."""
    means_c, quats_c = means_c.detach(), quats_c.detach()
    off_c = (means_c[nb] - means_c[idx, None]) / extent                 # (S, k, 3)
    off_t = (gather_rows(means_t, nb) - means_t[idx, None]) / extent
    rot_c = quat_to_rotmat(quats_c)
    rel = quat_to_rotmat(quats_t) @ rot_c.transpose(1, 2)                # (N', 3, 3) dR = R_t R_c^T
    # rel is computed for every row of quats_t given; index it for the sample and neighbours
    rel_i, rel_j = rel[idx], gather_rows(rel, nb)                                   # (S, 3, 3), (S, k, 3, 3)
    predicted = torch.einsum("sab,skb->ska", rel_i, off_c)
    wsum = weights.sum().clamp_min(1e-12)
    rigid = (weights * (off_t - predicted).norm(dim=-1)).sum() / wsum
    iso = (weights * (off_t.norm(dim=-1) - off_c.norm(dim=-1)).abs()).sum() / wsum
    rot = (weights * (rel_j - rel_i[:, None]).flatten(2).norm(dim=-1)).sum() / wsum
    return {"rigid": rigid, "iso": iso, "rot": rot}


def anisotropy(log_scales: torch.Tensor, max_aspect: float) -> torch.Tensor:
    """Mean excess of log(largest / smallest scale) over log(max_aspect). log_scales: (S, 3)."""
    spread = log_scales.max(dim=1).values - log_scales.min(dim=1).values
    return torch.relu(spread - torch.log(torch.tensor(max_aspect))).mean()


def acceleration(before: torch.Tensor, now: torch.Tensor, after: torch.Tensor, extent: float) -> torch.Tensor:
    """Mean squared second difference of positions (S, 3) at three equally spaced instants, in
    units of the scene extent."""
    return ((before - 2 * now + after) / extent).pow(2).sum(-1).mean()


class MotionPriors:
    """The priors of one training run: a k-NN graph over canonical means (rebuilt when the
    Gaussian count changes) and the weighted sum of the enabled terms."""

    def __init__(self, cfg: PriorConfig, extent: float):
        self.cfg = cfg
        self.extent = max(float(extent), 1e-9)
        self._n = -1
        self._neighbours: torch.Tensor | None = None

    @property
    def enabled(self) -> bool:
        c = self.cfg
        return any(w > 0 for w in (c.rigidity, c.isometry, c.rotation, c.smoothness, c.sparsity, c.anisotropy,
                                   c.static, c.residual_sparsity))

    def state(self) -> dict:
        return {"n": self._n, "neighbours": self._neighbours}

    def load_state(self, state: dict) -> None:
        self._n, self._neighbours = state["n"], state["neighbours"]

    def _graph(self, means: torch.Tensor) -> torch.Tensor:
        if means.shape[0] != self._n:
            self._neighbours = knn_indices(means.detach(), self.cfg.knn)
            self._n = means.shape[0]
        return self._neighbours

    def __call__(self, canonical: dict[str, torch.Tensor], deformed: dict[str, torch.Tensor],
                 geometry_at, t: float, dt: float, generator: torch.Generator
                 ) -> tuple[torch.Tensor, dict[str, float]]:
        """Weighted prior loss and its terms for logging.

        canonical / deformed: {"means": (N, 3), "quats": (N, 4)} at rest and at time t (deformed
        carries the graph of the deformation); canonical also has "log_scales" (N, 3) and, with a
        static/dynamic split, "dynamic" (N,) in {0, 1}. geometry_at(t, index) -> means (S, 3) of the
        Gaussians `index` at time t (only called for trajectory smoothness)."""
        cfg, n = self.cfg, canonical["means"].shape[0]
        zero = deformed["means"].sum() * 0
        if n < 2 or not self.enabled:
            return zero, {}
        idx = torch.randperm(n, generator=generator)[: cfg.sample]
        total, stats = zero, {}
        if cfg.rigidity > 0 or cfg.isometry > 0 or cfg.rotation > 0:
            nb = self._graph(canonical["means"])[idx]
            d2 = (canonical["means"].detach()[idx, None] - canonical["means"].detach()[nb]).pow(2).sum(-1)
            w = torch.exp(-cfg.knn_falloff * d2 / self.extent ** 2)
            if "dynamic" in canonical:      # static Gaussians do not move: only moving pairs count
                dyn = canonical["dynamic"]
                w = w * dyn[idx, None] * gather_rows(dyn, nb)
            rows = torch.unique(torch.cat([idx, nb.flatten()]))
            # rotations only for the rows used: remap indices into `rows`
            pos = torch.full((n,), -1, dtype=torch.long)
            pos[rows] = torch.arange(len(rows))
            terms = rigidity_terms(canonical["means"][rows], canonical["quats"][rows],
                                   deformed["means"][rows], deformed["quats"][rows],
                                   pos[idx], pos[nb], w, self.extent)
            for key, weight in (("rigid", cfg.rigidity), ("iso", cfg.isometry), ("rot", cfg.rotation)):
                if weight > 0:
                    total = total + weight * terms[key]
                    stats[key] = float(terms[key].detach())
        if cfg.anisotropy > 0:
            aniso = anisotropy(canonical["log_scales"][idx], cfg.max_aspect)
            total = total + cfg.anisotropy * aniso
            stats["aniso"] = float(aniso.detach())
        if cfg.sparsity > 0:
            moved = ((deformed["means"][idx] - canonical["means"][idx].detach()) / self.extent).norm(dim=-1).mean()
            total = total + cfg.sparsity * moved
            stats["sparse"] = float(moved.detach())
        if cfg.residual_sparsity > 0 and "means" in deformed.get("geometry_residuals", {}):
            residual = (deformed["geometry_residuals"]["means"][idx] / self.extent).norm(dim=-1).mean()
            total = total + cfg.residual_sparsity * residual
            stats["residual"] = float(residual.detach())
        if cfg.smoothness > 0 and dt > 0:
            s = idx[: cfg.smoothness_sample]
            t0 = min(max(t, dt), 1.0 - dt)                # a centred difference inside [0, 1]
            now = deformed["means"][s] if t0 == t else geometry_at(t0, s)
            acc = acceleration(geometry_at(t0 - dt, s), now, geometry_at(t0 + dt, s), self.extent)
            total = total + cfg.smoothness * acc
            stats["smooth"] = float(acc.detach())
        return total, stats


def body_warmth(colour: torch.Tensor, basis: torch.Tensor, members: torch.Tensor, band: float) -> torch.Tensor:
    """Mean over body members of how far each one's thermal colour lies beyond `band` from its
    body's median: relu(|c_i - median_b| - band). colour (N,) normalised temperature, basis (N,)
    body index (0 = static), members (N,) bool which Gaussians count (the gate open), band in the
    same units. The median is not differentiated: the members are pulled towards their body, not
    the body towards its outliers. Zero without members."""
    rows = torch.nonzero(members & (basis > 0)).view(-1)
    if len(rows) == 0:
        return colour.sum() * 0
    c, b = colour.index_select(0, rows), basis.index_select(0, rows).long()
    medians = torch.stack([c[b == k].detach().median() if bool((b == k).any()) else c.new_zeros(())
                           for k in range(int(b.max()) + 1)])
    return torch.relu((c - medians[b]).abs() - band).mean()
