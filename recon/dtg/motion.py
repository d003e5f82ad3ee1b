"""Rigid motion bases: what moves, moves as a body along a path (Shape of Motion's low-rank
SE(3) motion, with one basis per Gaussian).

A moving object of the scene family is a rigid body: every point of it follows the same rotation
and translation. A deformation network or per-Gaussian trajectories give each Gaussian its own
path; with one view per instant nothing then ties the Gaussians of one object together, and each
can slide along its training ray (right in the training view, smeared from any other). Here
moving Gaussians belong to one of B bases, each an SE(3) trajectory: a rotation (axis-angle)
and a translation per time knot, about a fixed pivot (the centre of the Gaussians it was built
from). All pixels of an object then pull on the same six numbers per instant, its shape is shared
by every instant, and so its apparent size and its RGB-thermal parallax fix its depth.

Per Gaussian (``recon/dtg/gaussians.py``): ``motion_basis`` (N,) the basis index, 0 = static (not
learned; children of a densified Gaussian inherit it), and the gate ``dynamic_logit`` (N,): a
Gaussian moves by sigmoid(gate) of its basis' motion, so a background point that was put in a
basis (it lay on a moving object's path) can learn to stay.
"""
from __future__ import annotations

import torch
from torch import nn

from recon.dtg import _native
from recon.dtg.neighbours import knn_mean_sq_dist
from recon.dtg.time_embedding import lerp_rows


def axis_angle_to_quat(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 4) wxyz unit quaternion."""
    theta2 = (v * v).sum(-1, keepdim=True)
    theta = theta2.clamp_min(1e-12).sqrt()
    half = 0.5 * theta
    s = torch.where(theta2 < 1e-8, 0.5 - theta2 / 48, torch.sin(half) / theta)
    return torch.cat([torch.cos(half), v * s], -1)


class MotionBases(nn.Module):
    """B rigid trajectories over K time knots: rotation (B, K, 3) axis-angle about pivots (B, 3)
    and translation (B, K, 3), linear between knots; all identity at start."""

    def __init__(self, pivots: torch.Tensor, knots: int, radii: torch.Tensor | None = None):
        super().__init__()
        b = pivots.shape[0]
        self.register_buffer("pivots", pivots.clone().float())
        # how far a body's Gaussians may reach from its pivot (0: unbounded; keep_within)
        self.register_buffer("radii", torch.zeros(b) if radii is None else radii.clone().float())
        self.rotation = nn.Parameter(torch.zeros(b, knots, 3))
        self.translation = nn.Parameter(torch.zeros(b, knots, 3))
        # translation knots measured outside the training loss (recon/train/paths.py), where
        # `anchored` (B, K) is set; PriorConfig.path_anchor holds them there (anchor_pull)
        self.register_buffer("anchors", torch.zeros(b, knots, 3))
        self.register_buffer("anchored", torch.zeros(b, knots, dtype=torch.bool))
        # (B, K, 3, 3) inverse covariance (1/m^2) of the anchors by their own fit (paths.knot_covariance):
        # PriorConfig.path_hold holds each knot as firmly as the thermal frames measured it (hold_cost)
        self.register_buffer("anchor_precision", torch.zeros(b, knots, 3, 3))

    @property
    def count(self) -> int:
        return self.pivots.shape[0]

    def at(self, t: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(rotation (B, 3) axis-angle, translation (B, 3)) at time t."""
        return lerp_rows(self.rotation, t, dim=1), lerp_rows(self.translation, t, dim=1)

    @torch.no_grad()
    def keep_within(self, means: torch.Tensor, log_scales: torch.Tensor, basis: torch.Tensor,
                    scale_share: float = 0.5) -> None:
        """In place: each body's Gaussians (means (N, 3) canonical, log_scales (N, 3), basis (N,))
        stay within its radius of its pivot, none larger than scale_share of it. A body is one
        object: without a bound its Gaussians spread over the frame to fit whatever the static
        scene gets wrong, and a cloud cannot be tracked."""
        if not bool((self.radii > 0).any()):
            return
        idx = (basis > 0).nonzero()[:, 0]
        b = basis[idx].long() - 1
        r = self.radii[b]
        keep = r > 0
        idx, b, r = idx[keep], b[keep], r[keep]
        off = means[idx] - self.pivots[b]
        dist = off.norm(dim=1).clamp_min(1e-12)
        means[idx] = self.pivots[b] + off * (r / dist).clamp(max=1.0)[:, None]
        log_scales[idx] = torch.minimum(log_scales[idx], torch.log(scale_share * r)[:, None])

    def smoothness(self, extent: float, scale: float = 0.0) -> torch.Tensor:
        """Squared second difference of rotation (rad) and translation (in scene extents), summed
        over bases and averaged over knots: each basis' acceleration, whatever the basis count.

        It is what fixes a moving object's depth. With one view per instant, an object scaled by s
        about the camera, X'(t) = s X(t) + (1 - s) C(t), looks the same in every training frame; a
        handheld camera centre C(t) accelerates far more than the objects it films, so only s = 1
        keeps the trajectory smooth.

        scale > 0: each knot's acceleration a costs the pseudo-Huber 2 s^2 (sqrt(1 + |a|^2 / s^2) - 1)
        instead: |a|^2 below s, 2 s |a| above (``robust_square``). A depth error adds acceleration at
        every knot, while an object that starts or stops (a ball that rolls and comes to rest) has
        one large kink: squared, that kink costs about half as much as a 10 % depth error over the
        whole path of a handheld sweep (tests/test_motion.py; PriorConfig.basis_smoothness_scale)."""
        if self.rotation.shape[1] < 3:
            return self.rotation.sum() * 0
        def acc(x):
            sq = (x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]).pow(2).sum(-1)
            return (robust_square(sq, scale) if scale > 0 else sq).mean(1).sum()
        return acc(self.rotation) + acc(self.translation / extent)

    def anchor_pull(self, extent: float) -> torch.Tensor:
        """Squared distance (in scene extents) of the anchored translation knots from their anchors,
        averaged over each basis' knots and summed over bases.

        The training views prefer a wrong depth for a moving body (docs/training.md, "Where a path's
        depth goes wrong"): unheld, a triangulated path drifts along the rays while the rest of
        the scene fits around it."""
        off = (self.translation - self.anchors) / extent
        return (off.pow(2).sum(-1) * self.anchored).mean(1).sum()

    def hold_cost(self) -> torch.Tensor:
        """Squared Mahalanobis distance of the anchored translation knots from their anchors under
        the anchors' own covariance (how many standard deviations of the triangulation each knot
        moved, squared), averaged over each basis' knots and summed over bases.

        A path the rig's sweep measured well (a few cm) is held; one it could not measure along the
        rays (tens of cm) is left to the training views: an isotropic pull (anchor_pull) held both
        alike, and on the paths 8-17 cm off it cost what it gained elsewhere."""
        off = self.translation - self.anchors
        cost = torch.einsum("bki,bkij,bkj->bk", off, self.anchor_precision, off)
        return (cost * self.anchored).mean(1).sum()

    def climb(self, up: torch.Tensor, extent: float) -> torch.Tensor:
        """Squared vertical speed of each basis' translation (in scene extents per knot) along
        up (3,), summed over bases and averaged over knots.

        Things that move on a table or a floor keep their height, and a view that looks down at a
        body turns its height into its depth along the ray: the one direction that a single view
        cannot measure (PriorConfig.level_paths)."""
        if self.translation.shape[1] < 2:
            return self.translation.sum() * 0
        rise = (self.translation[:, 1:] - self.translation[:, :-1]) @ up.to(self.translation) / extent
        return rise.pow(2).mean(1).sum()


# L(q) @ p = q * p (Hamilton product, wxyz) and R(q) @ p = p * q, as gathers of q's entries with
# signs: one index and one multiply in the autograd graph instead of 16 stacked scalars.
_LEFT = (torch.tensor([0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0]),
         torch.tensor([1, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1.0]))
_RIGHT_CONJ = (_LEFT[0], torch.tensor([1, 1, 1, 1, -1, 1, -1, 1, -1, 1, 1, -1, -1, -1, 1, 1.0]))


def robust_square(sq: torch.Tensor, scale: float) -> torch.Tensor:
    """Pseudo-Huber of squared norms sq (...): 2 s^2 (sqrt(1 + sq / s^2) - 1), ~sq below s^2 and
    ~2 s sqrt(sq) above: a few large values cost linearly, many small ones as squares."""
    s2 = scale * scale
    return 2 * s2 * (torch.sqrt(1 + sq / s2) - 1)


def quat_matrix(q: torch.Tensor, table: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """(..., 4) wxyz -> (..., 4, 4): _LEFT gives L(q), _RIGHT_CONJ R(conj(q))."""
    index, sign = table
    return (q.index_select(-1, index.to(q.device)) * sign.to(q)).view(*q.shape[:-1], 4, 4)


def body_transforms(bases: "MotionBases", t: float) -> torch.Tensor:
    """(B, 28) each body's motion at time t, packed: rotation matrix R (9), offset c (3) and L (16),
    the left multiplication by its rotation quaternion q. A point mu moves to R mu + c (rotation
    about the pivot, then translation), an orientation to L q'. R is the lower 3x3 block of
    L(q) R(conj(q)) (p -> q p conj(q)). On the CPU (float32 / float64) the native kernel computes
    them and their VJP from the knots' interpolation (~25 autograd nodes on a few rows in torch);
    elsewhere body_transforms_reference."""
    rot, trans = bases.at(t)
    if not _native_fits(rot):
        return body_transforms_reference(rot, trans, bases.pivots)
    return BodyTransforms.apply(rot, trans, bases.pivots.to(rot.dtype))


def body_transforms_reference(rot: torch.Tensor, trans: torch.Tensor, pivots: torch.Tensor) -> torch.Tensor:
    """body_transforms in torch ops from the bodies' rotations, translations and pivots (B, 3) each:
    any device, and the reference the native kernel is tested against."""
    q = axis_angle_to_quat(rot)                                       # (B, 4)
    left = quat_matrix(q, _LEFT)
    r = (left @ quat_matrix(q, _RIGHT_CONJ))[:, 1:, 1:]               # (B, 3, 3)
    c = pivots + trans - (r @ pivots[:, :, None])[:, :, 0]
    return torch.cat([r.flatten(1), c, left.flatten(1)], 1)


class BodyTransforms(torch.autograd.Function):
    """The native body_transforms in autograd: (rotation, translation, pivots (B, 3) each) -> (B, 28).
    The pivots get no gradient."""

    @staticmethod
    def forward(ctx, rot, trans, pivots):
        ctx.save_for_backward(rot, trans, pivots)
        return torch.from_numpy(getattr(_native, f"transforms_forward_{_dtype(rot)}")(_np(rot), _np(trans), _np(pivots)))

    @staticmethod
    def backward(ctx, v):
        d_rot, d_trans = getattr(_native, f"transforms_backward_{_dtype(v)}")(
            *[_np(x) for x in ctx.saved_tensors], _np(v))
        return torch.from_numpy(d_rot), torch.from_numpy(d_trans), None


def apply_motion(means: torch.Tensor, quats: torch.Tensor | None, basis: torch.Tensor, gate: torch.Tensor,
                 bases: MotionBases, t: float) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Move Gaussians with their basis at time t.

    means (N, 3), quats (N, 4) wxyz or None (then only the means are moved), basis (N,) float
    index (0 = static, b >= 1 = bases row b-1), gate (N,) in [0, 1]: a Gaussian goes that share
    of the way. Returns moved (means, quats); static Gaussians are returned unchanged.
    On the CPU in float32 or float64 the native kernel (recon/dtg/csrc/motion.cpp) does it in one
    pass; elsewhere apply_motion_reference, the same motion in torch ops."""
    if not bool((basis > 0).any()):
        return means, quats
    transforms = body_transforms(bases, t)
    if not _native_fits(means):
        return apply_motion_reference(means, quats, basis, gate, transforms)
    empty = means.new_zeros(0, 4)
    moved, turned = BodyMotion.apply(means, empty if quats is None else quats, basis.to(means.dtype),
                                     gate.to(means.dtype), transforms.to(means.dtype))
    return moved, (None if quats is None else turned)


def apply_motion_reference(means: torch.Tensor, quats: torch.Tensor | None, basis: torch.Tensor, gate: torch.Tensor,
                           transforms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """apply_motion in torch ops, with the bodies' packed transforms (B, 28) (body_transforms): any
    device, and the reference the native kernel is tested against."""
    idx = basis.long()
    moving = (idx > 0).nonzero()[:, 0]
    # index_select, not x[idx]: its backward is an index_add, ~3x faster on CPU than index_put's
    per = transforms.index_select(0, idx.index_select(0, moving) - 1)    # (M, 28)
    g = gate.index_select(0, moving)[:, None]
    mu = means.index_select(0, moving)
    # bmm, not a broadcast product and a sum: ~30 % less time forward + backward at 13k Gaussians
    moved = torch.bmm(per[:, :9].view(-1, 3, 3), mu[:, :, None])[:, :, 0] + per[:, 9:12]
    means = means.index_copy(0, moving, torch.lerp(mu, moved, g))
    if quats is not None:
        q = quats.index_select(0, moving)
        turned = torch.bmm(per[:, 12:].view(-1, 4, 4), q[:, :, None])[:, :, 0]
        quats = quats.index_copy(0, moving, torch.lerp(q, turned, g))
    return means, quats


class BodyMotion(torch.autograd.Function):
    """The native kernel in autograd: (means (N,3), quats (N,4) or (0,4) for none, basis (N,),
    gate (N,), transforms (B,28)) -> (moved means (N,3), turned quats (N,4) or (0,4)). basis gets no
    gradient."""

    @staticmethod
    def forward(ctx, means, quats, basis, gate, transforms):
        args = [_np(x) for x in (means, quats, basis, gate, transforms)]
        moved, turned = getattr(_native, f"forward_{_dtype(means)}")(*args)
        ctx.save_for_backward(means, quats, basis, gate, transforms)
        return torch.from_numpy(moved), torch.from_numpy(turned)

    @staticmethod
    def backward(ctx, v_means, v_quats):
        saved = [_np(x) for x in ctx.saved_tensors]
        grads = getattr(_native, f"backward_{_dtype(v_means)}")(*saved, _np(v_means), _np(v_quats))
        d_means, d_quats, d_gate, d_transforms = (torch.from_numpy(g) for g in grads)
        return d_means, d_quats, None, d_gate, d_transforms


def _native_fits(t: torch.Tensor) -> bool:
    """The native kernels take CPU tensors of float32 or float64."""
    return t.device.type == "cpu" and t.dtype in (torch.float32, torch.float64)


def _np(t: torch.Tensor):
    return t.detach().contiguous().numpy()


def _dtype(t: torch.Tensor) -> str:
    return str(t.dtype).removeprefix("torch.")


def body_radii(points: torch.Tensor, basis: torch.Tensor, pivots: torch.Tensor, reach: float) -> torch.Tensor:
    """(B,) how far each body may reach: `reach` x its farthest point (points (M, 3), basis (M,)
    1-based) from its pivot (B, 3); zeros (unbounded) when reach is 0."""
    radii = torch.zeros(len(pivots))
    if reach <= 0:
        return radii
    for b in range(len(pivots)):
        mine = points[basis == b + 1]
        if len(mine):
            radii[b] = reach * float((mine - pivots[b]).norm(dim=1).max())
    return radii


def connected_clusters(points: torch.Tensor, radius: float) -> torch.Tensor:
    """Single-linkage clusters: points closer than `radius` (through a chain of such points) share
    a label. points (M, 3) -> labels (M,) in [0, clusters), largest cluster first."""
    m = points.shape[0]
    parent = list(range(m))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for start in range(0, m, 1024):
        close = (torch.cdist(points[start:start + 1024], points) < radius).nonzero().tolist()
        for i, j in close:
            a, b = find(start + i), find(j)
            if a != b:
                parent[max(a, b)] = min(a, b)
    roots = torch.tensor([find(i) for i in range(m)])
    _, inverse, counts = torch.unique(roots, return_inverse=True, return_counts=True)
    order = torch.argsort(counts, descending=True)
    rank = torch.empty_like(order)
    rank[order] = torch.arange(len(order))
    return rank[inverse]


def body_clusters(points: torch.Tensor, min_points: int, max_bodies: int) -> list[torch.Tensor]:
    """The rigid bodies among points (M, 3) on moving objects: connected groups (connected_clusters,
    linked within 3x the points' median nearest-neighbour spacing) of at least `min_points`, largest
    first, at most `max_bodies`; each as indices into points."""
    if len(points) < 2:
        labels = torch.zeros(len(points), dtype=torch.long)
    else:
        spacing = knn_mean_sq_dist(points, k=1).sqrt().median()
        labels = connected_clusters(points, float(3 * spacing))
    sizes = torch.bincount(labels)
    return [(labels == k).nonzero()[:, 0] for k in range(len(sizes)) if sizes[k] >= min_points][:max_bodies]
