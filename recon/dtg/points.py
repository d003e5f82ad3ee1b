"""What the initial points tell before training: each point's temperature, and whether the scene
changes there.

Both come from sampling the training images where a point projects (nearest pixel). For the
change test a point counts only in views where no other initial point lies in front of it (a
z-buffer of the points), so the back of a static box does not read as changing; a point behind
a passing object still does: it may move, and the motion priors keep it in place if it need not.
"""
from __future__ import annotations

import numpy as np
import torch

from recon.scene import Scene, View


def point_depth_buffer(u: torch.Tensor, v: torch.Tensor, z: torch.Tensor, ok: torch.Tensor,
                       width: int, height: int, radius: int) -> torch.Tensor:
    """Nearest depth (H, W) of points drawn as (2 radius + 1)^2 pixel squares (inf where none)."""
    zbuf = torch.full((height * width,), torch.inf)
    for du in range(-radius, radius + 1):
        for dv in range(-radius, radius + 1):
            uu, vv = u + du, v + dv
            keep = ok & (uu >= 0) & (uu < width) & (vv >= 0) & (vv < height)
            zbuf.scatter_reduce_(0, (vv * width + uu)[keep], z[keep], reduce="amin")
    return zbuf.view(height, width)


def in_front(u: torch.Tensor, v: torch.Tensor, z: torch.Tensor, ok: torch.Tensor, width: int, height: int,
             radius: int, tolerance: float) -> torch.Tensor:
    """ok (M,) narrowed to the points (pixels u, v (M,), camera depths z (M,)) with no other point
    of ok in front of them: none more than `tolerance` relatively nearer within `radius` pixels."""
    zbuf = point_depth_buffer(u, v, z, ok, width, height, radius)
    return ok & (z <= zbuf[v.clamp(0, height - 1), u.clamp(0, width - 1)] * (1 + tolerance))


def project(camera, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pixels of points (M, 3) in a camera: (u (M,), v (M,) integer pixel, camera z (M,), in view
    (M,) bool: in front and inside the image)."""
    pc = points @ camera.viewmat[:3, :3].T + camera.viewmat[:3, 3]
    z = pc[:, 2]
    u = (camera.fx * pc[:, 0] / z.clamp_min(1e-6) + camera.cx).floor().long()
    v = (camera.fy * pc[:, 1] / z.clamp_min(1e-6) + camera.cy).floor().long()
    return u, v, z, (z > 1e-3) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)


def colour_distance(image: torch.Tensor, u: torch.Tensor, v: torch.Tensor, colors: torch.Tensor,
                    radius: int = 1) -> torch.Tensor:
    """(M,) smallest max-channel |image - colour| over the (2 radius + 1)^2 pixels around (u, v)
    (M,): what a point of colour colors (M, 3) reads from an image (H, W, 3), forgiving texture and
    rounding."""
    h, w = image.shape[:2]
    best = torch.full((len(u),), torch.inf)
    for du in range(-radius, radius + 1):
        for dv in range(-radius, radius + 1):
            uu, vv = (u + du).clamp(0, w - 1), (v + dv).clamp(0, h - 1)
            best = torch.minimum(best, (image[vv, uu] - colors).abs().amax(-1))
    return best


def sample_views(scene: Scene, views: list[View], points: torch.Tensor, occlusion_radius: int = 0,
                 occlusion_tolerance: float = 0.05) -> tuple[torch.Tensor, torch.Tensor]:
    """What each view sees where each point projects. points: (M, 3) ->
    (values (V, M, C): RGB in [0, 1] or normalised temperature (C = 1), seen (V, M) bool).
    occlusion_radius > 0: a point counts as seen only if no other point lies in front of it
    (depth more than `occlusion_tolerance` relatively smaller) within that many pixels."""
    values, seen = [], []
    for view in views:
        target, valid = scene.target(view)
        target = target if target.dim() == 3 else target[..., None]
        cam = view.camera
        u, v, z, ok = project(cam, points)
        uu, vv = u.clamp(0, cam.width - 1), v.clamp(0, cam.height - 1)
        if valid is not None:
            ok &= valid[vv, uu]
        if occlusion_radius > 0:
            ok = in_front(u, v, z, ok, cam.width, cam.height, occlusion_radius, occlusion_tolerance)
        values.append(target[vv, uu])
        seen.append(ok)
    return torch.stack(values), torch.stack(seen)


def seen_mean(scene: Scene, views: list[View], points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(M, C) mean of what views see where points (M, 3) project, and (M,) bool whether any view
    sees the point (its mean is 0 where none does)."""
    values, seen = sample_views(scene, views, points)
    count = seen.sum(0)
    return (values * seen[..., None]).sum(0) / count.clamp_min(1)[:, None], count > 0


def initial_temperatures(scene: Scene, points: torch.Tensor, max_views: int = 6) -> torch.Tensor | None:
    """Normalised temperature of each point, averaged over a few thermal training views that see it.
    Points no view sees get the median. -> (M,) or None."""
    views = scene.train["thermal"]
    if not views:
        return None
    picks = [views[i] for i in np.linspace(0, len(views) - 1, min(max_views, len(views))).round().astype(int)]
    mean, seen = seen_mean(scene, picks, points)
    fill = mean[seen, 0].median() if seen.any() else torch.tensor(0.5)
    return torch.where(seen, mean[:, 0], fill).clamp(0, 1)


def changing_points(scene: Scene, points: torch.Tensor, rgb_change: float, kelvin_change: float,
                    fraction: float) -> torch.Tensor:
    """(M,) bool: points where the training views see the scene change over time: in more than
    `fraction` of the views that see a point, its RGB differs from the point's median colour by
    more than `rgb_change` (max over channels) or its temperature from its median by more than
    `kelvin_change` kelvin. A static surface reads the same from every view (Lambertian colour, a
    slowly changing temperature); a point on a moving object's path does not."""
    changing = torch.zeros(len(points), dtype=torch.bool)
    span = scene.k_max - scene.k_min
    for modality, limit in (("rgb", rgb_change), ("thermal", kelvin_change / span)):
        views = scene.train[modality]
        if not views:
            continue
        values, seen = sample_views(scene, views, points, occlusion_radius=2)
        masked = torch.where(seen[..., None], values, torch.nan)
        median = masked.nanmedian(dim=0).values                       # (M, C)
        off = ((values - median).abs().amax(-1) > limit) & seen        # (V, M)
        changing |= off.sum(0) > fraction * seen.sum(0).clamp_min(1)
    return changing


def observed_time(scene: Scene, points: torch.Tensor, colors: torch.Tensor, tolerance: float = 0.12
                  ) -> tuple[float, torch.Tensor] | None:
    """When the moving points were seen, and which of them are there then.

    An SfM cloud holds a moving object where some frame saw it (a simulator's cloud may hold it
    at several instants: ghosts along its path). The training time whose RGB views agree best
    with the points' own colours is when they were seen; the points that agree with the views of
    that instant are the objects as they were then. points (M, 3), colors (M, 3) in [0, 1] ->
    (time, matched (M,) bool), or None without points or RGB views."""
    views = scene.train["rgb"]
    if not views or len(points) == 0:
        return None
    values, seen = sample_views(scene, views, points, occlusion_radius=2)
    match = ((values - colors[None]).abs().amax(-1) < tolerance) & seen        # (V, M)
    score = match.sum(1).float() / seen.sum(1).clamp_min(1)
    per_time: dict[float, list[int]] = {}
    for i, v in enumerate(views):
        per_time.setdefault(v.time, []).append(i)
    best = max(per_time, key=lambda t: (float(score[per_time[t]].mean()), -abs(t - 0.5)))
    return float(best), match[per_time[best]].any(0)


def colour_seen_fraction(scene: Scene, points: torch.Tensor, colors: torch.Tensor, tolerance: float = 0.1,
                         radius: int = 1) -> torch.Tensor:
    """(M,) share of the RGB training views that see each point (M, 3) and show its own colour
    (M, 3) in [0, 1] within `tolerance` (max over channels) anywhere in a (2 radius + 1)^2 pixel
    neighbourhood of its projection (texture and rounding); NaN where no view sees it. A static
    point reads its colour from nearly every view; a point of a moving object, recorded at one
    instant, only while the object is still there."""
    hits = torch.zeros(len(points))
    seen = torch.zeros(len(points))
    for view in scene.train["rgb"]:
        target, _ = scene.target(view)
        u, v, _, ok = project(view.camera, points)
        hits += (ok & (colour_distance(target, u, v, colors, radius) < tolerance)).float()
        seen += ok.float()
    return torch.where(seen > 0, hits / seen.clamp_min(1), torch.nan)


def transient_points(scene: Scene, points: torch.Tensor, colors: torch.Tensor, tolerance: float = 0.1,
                     radius: int = 1, fraction: float = 0.3) -> torch.Tensor:
    """(M,) bool: points whose own colour the RGB training views show in less than `fraction` of
    the views that see them (colour_seen_fraction). Measured on 5 family scenes at 0.3: 25-63 of
    150-260 points on moving objects, 1-5 of 3500-3800 others (objects with the floor's colour are
    not found)."""
    share = colour_seen_fraction(scene, points, colors, tolerance, radius)
    return ~share.isnan() & (share < fraction)
