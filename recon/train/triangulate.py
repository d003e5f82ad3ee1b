"""Moving bodies' depth from the camera's own motion (``CurriculumConfig.triangulate_every``).

With one training view per instant, a body's photometric fit pins where it is *in the image* but
not how far along the camera's ray: shape, colour and the static scene fit whatever depth the
constant-velocity guess gave the step when the window took it in, and training never corrects it
(docs/training.md, "Where a path's depth goes wrong"). A handheld rig moves, though: the rays
through a body's image at successive instants come from camera centres tens of centimetres apart.
Of all the paths that stay on those rays, the true one is the smooth one (MotionBases.smoothness:
the camera accelerates far more than the objects it films). So, now and then, each body's centre
is re-solved over the knots its window holds: one linear least-squares problem per body,

    min_p  sum_k w_k |(I - d_k d_k^T)(p_k - c_k)|^2  +  smooth sum_k |p_{k-1} - 2 p_k + p_{k+1}|^2
           + anchor sum_k |p_k - x_k|^2

(c_k: the training camera's centre at knot k, d_k: its unit ray through the body's centre x_k,
w_k = 1 where the body is in that view), and each knot slides along its own ray to the solved
depth: its pixel stays, its depth follows from the whole path. Both terms are squared lengths,
so ``smooth`` does not depend on the scene's scale. The body's shape is rescaled about its centre
by the median ratio of new to old depth, so it keeps the size it has in the images.
"""
from __future__ import annotations

import torch

from recon.dtg.motion import apply_motion

ANCHOR = 1e-8       # the gauge: where nothing else decides (no camera motion), knots stay
# The smoothest path is the true one only where the camera accelerates more than the objects it
# films (a handheld sweep: ~10x on the scene family); a body is left alone where its own path
# accelerates more than 1/MIN_ACCELERATION_RATIO of the camera's.
MIN_ACCELERATION_RATIO = 4.0
MAX_DEPTH_RATIO = 2.0  # one solve moves a knot at most this factor nearer or farther


def smooth_path(centres: torch.Tensor, rays: torch.Tensor, weights: torch.Tensor, anchor: torch.Tensor,
                smooth: float, anchor_weight: float = ANCHOR) -> torch.Tensor:
    """(K, 3) the path p minimising the docstring's objective (float64 inside).

    centres: (K, 3) camera centres, rays: (K, 3) unit directions, weights: (K,) (0: no ray at that
    knot), anchor: (K, 3) where each knot is now."""
    k = centres.shape[0]
    c, d, w, x = (v.double() for v in (centres, rays, weights, anchor))
    proj = torch.eye(3, dtype=torch.float64) - d[:, :, None] * d[:, None, :]         # (K, 3, 3)
    h = torch.zeros(k, 3, k, 3, dtype=torch.float64)
    idx = torch.arange(k)
    h[idx, :, idx, :] = w[:, None, None] * proj + anchor_weight * torch.eye(3, dtype=torch.float64)
    rhs = w[:, None] * (proj @ c[:, :, None])[:, :, 0] + anchor_weight * x
    if k >= 3:
        second = torch.zeros(k - 2, k, dtype=torch.float64)
        rows = torch.arange(k - 2)
        second[rows, rows], second[rows, rows + 1], second[rows, rows + 2] = 1.0, -2.0, 1.0
        h += smooth * (second.T @ second)[:, None, :, None] * torch.eye(3, dtype=torch.float64)[None, :, None, :]
    p = torch.linalg.solve(h.reshape(3 * k, 3 * k), rhs.reshape(-1))
    return p.reshape(k, 3).to(centres.dtype)


def camera_pins_depth(eyes: torch.Tensor, centres: torch.Tensor, weights: torch.Tensor,
                      min_ratio: float = MIN_ACCELERATION_RATIO) -> bool:
    """Whether the camera's motion tells depth apart: over consecutive knot triples with rays
    (weights > 0), the camera centres' (eyes (K, 3)) squared acceleration is at least min_ratio x
    the body's (centres (K, 3)). Scaling a path about a still camera changes only its own
    acceleration, so without the camera's the smoothest path would collapse onto the camera."""
    on = weights > 0
    both = on[2:] & on[1:-1] & on[:-2]
    if int(both.sum()) < 3:
        return False
    acc = lambda x: (x[2:] - 2 * x[1:-1] + x[:-2])[both].pow(2).sum()  # noqa: E731
    return float(acc(eyes)) >= min_ratio * float(acc(centres))


def knot_cameras(scene, modality: str, knots: int, lo: float, hi: float) -> dict[int, list]:
    """{knot: [cameras of modality's training views at its time]} for the times in [lo, hi]."""
    out: dict[int, list] = {}
    for t in scene.times:
        if lo - 1e-9 <= t <= hi + 1e-9:
            for view in scene.views_at(modality, t):
                out.setdefault(round(t * (knots - 1)), []).append(view.camera)
    return out


def in_view(camera, point: torch.Tensor) -> bool:
    """Whether point (3,) projects into camera's image in front of it."""
    pc = camera.viewmat[:3, :3] @ point + camera.viewmat[:3, 3]
    if float(pc[2]) <= 1e-3:
        return False
    u = float(camera.fx * pc[0] / pc[2] + camera.cx)
    v = float(camera.fy * pc[1] / pc[2] + camera.cy)
    return 0 <= u < camera.width and 0 <= v < camera.height


@torch.no_grad()
def retriangulate(model, scene, lo: float, hi: float, smooth: float, modality: str = "rgb",
                  min_rays: int = 6, min_opacity_mass: float = 1.0, member_gate: float = 0.5) -> list[dict]:
    """Slide every body's knots in [lo, hi] (times) along their training rays to the depths of the
    smoothest path through them (module docstring), and rescale its members (gate > member_gate)
    about its centre. -> per body moved: {body, knots, rays, depth_change (median |m|), scale}."""
    motion = model.motion
    if motion is None or motion.count == 0:
        return []
    g = model.gaussians
    knots = motion.translation.shape[1]
    cams = knot_cameras(scene, modality, knots, lo, hi)
    if len(cams) < min_rays:
        return []
    k_lo, k_hi = min(cams), max(cams)
    span = torch.arange(k_lo, k_hi + 1)
    basis, gate = g["motion_basis"].long(), model.dynamic_gate()
    weight = torch.sigmoid(g[f"opacity_{modality}"]) * gate
    report = []
    for b in range(motion.count):
        sel = (basis == b + 1).nonzero()[:, 0]
        w = weight[sel]
        if float(w.sum()) < min_opacity_mass:
            continue
        mean_gate = float((gate[sel] * w).sum() / w.sum())
        if mean_gate < 0.05:
            continue
        centre = torch.stack([(apply_motion(g["means"][sel], None, g["motion_basis"][sel], gate[sel], motion,
                                            int(k) / (knots - 1))[0] * w[:, None]).sum(0) / w.sum() for k in span])
        eye = torch.zeros(len(span), 3)
        ray = torch.zeros(len(span), 3)
        rays = torch.zeros(len(span))
        for i, k in enumerate(span.tolist()):
            seen = [c for c in cams.get(k, []) if in_view(c, centre[i])]
            if seen:
                eye[i] = seen[0].center
                ray[i] = torch.nn.functional.normalize(centre[i] - eye[i], dim=0)
                rays[i] = 1.0
        if int(rays.sum()) < min_rays or not camera_pins_depth(eye, centre, rays):
            continue
        path = smooth_path(eye, ray, rays, centre, smooth)
        on = rays > 0
        depth_old = ((centre - eye) * ray).sum(1)
        depth_new = torch.minimum(((path - eye) * ray).sum(1).clamp_min(depth_old / MAX_DEPTH_RATIO),
                                  depth_old * MAX_DEPTH_RATIO)
        target = torch.where(on[:, None], eye + depth_new[:, None] * ray, path)
        motion.translation.data[b, span] += (target - centre) / mean_gate
        scale = float((depth_new[on] / depth_old[on]).median())
        members = sel[gate[sel] > member_gate]
        if abs(scale - 1) > 1e-3 and len(members):
            wm = weight[members]
            c0 = (g["means"][members] * wm[:, None]).sum(0) / wm.sum()
            g["means"].data[members] = c0 + scale * (g["means"][members] - c0)
            g["log_scales"].data[members] += torch.log(torch.tensor(scale))
        report.append({"body": b, "knots": len(span), "rays": int(rays.sum()),
                       "depth_change": float((depth_new[on] - depth_old[on]).abs().median()), "scale": scale})
    return report
