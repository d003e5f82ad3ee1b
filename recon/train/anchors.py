"""Depth anchors: where the initial points say a training view's surface is (sparse depth
supervision, as DS-NeRF does with SfM points; here with each point's instant found by colour).

An SfM cloud (or the simulator's) holds a surface point where some frame saw it, at its depth. A
static point is seen, with its own colour, by every view in which no other point lies in front of
it; a point of a moving object only by the frames of the instant it was recorded (at every other
instant it floats where the object is no longer, a ghost). So a point anchors the rendered depth
of each RGB training view that sees it unoccluded and shows its colour there. A point the views
see change (`changing_points`) anchors only the views within a step of the one that shows its
colour best, the instant it was recorded (a textured object matches other places at other times),
and only if that match is close.

One view cannot tell how far a moving object is (distance and speed trade off), and the bodies'
paths drift along the training rays (docs/training.md, "Where a path's depth goes wrong"); a
moving point's anchor is depth measured from outside those views.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from recon.dtg.points import colour_distance, in_front, project
from recon.scene import Scene


@dataclass
class DepthAnchors:
    points: torch.Tensor                  # (M, 3) world positions
    moving: torch.Tensor                  # (M,) bool: a changing point (its instant found by colour)
    by_view: dict[str, torch.Tensor]      # RGB training frame path -> (K,) indices into points

    def count(self) -> tuple[int, int]:
        """(static, moving) anchors over all views."""
        static = sum(int((~self.moving[i]).sum()) for i in self.by_view.values())
        moving = sum(int(self.moving[i].sum()) for i in self.by_view.values())
        return static, moving


def find_anchors(scene: Scene, points: torch.Tensor, colors: torch.Tensor, changing: torch.Tensor,
                 tolerance: float = 0.1, occlusion_radius: int = 2, occlusion_tolerance: float = 0.05,
                 near_steps: int = 1) -> DepthAnchors:
    """Anchors of points (M, 3) with colours (M, 3) in [0, 1] in the scene's RGB training views.
    changing (M,) bool: points whose views see the scene change (recon/dtg/points.changing_points).
    A view anchors a point that projects into it with no other point in front of it (within
    occlusion_radius pixels, occlusion_tolerance relatively nearer) and whose colour it shows
    within `tolerance` (max over channels, nearest of 3x3 pixels). A changing point keeps only the
    views within near_steps time steps of its best-matching one, if that matches within
    tolerance / 2."""
    views = scene.train["rgb"]
    distance = torch.full((len(views), len(points)), torch.inf)
    for i, view in enumerate(views):
        target, _ = scene.target(view)
        cam = view.camera
        u, v, z, ok = project(cam, points)
        ok = in_front(u, v, z, ok, cam.width, cam.height, occlusion_radius, occlusion_tolerance)
        distance[i] = torch.where(ok, colour_distance(target, u, v, colors, radius=1), torch.inf)
    match = distance < tolerance
    times = torch.tensor([v.time for v in views])
    step = 1.0 / max(scene.steps_per_unit_time() - 1, 1)
    best = distance.min(0)
    near = (times[:, None] - times[best.indices][None]).abs() <= near_steps * step + 1e-9
    match &= ~changing[None] | (near & (best.values < tolerance / 2)[None])
    by_view = {str(v.frame.file_path): torch.nonzero(match[i]).view(-1) for i, v in enumerate(views)}
    return DepthAnchors(points.float(), changing.clone(), by_view)


def anchor_loss(anchors: DepthAnchors, frame_path: str, camera, depth: torch.Tensor, alpha: torch.Tensor,
                moving: bool = True, tolerance: float = 0.0) -> dict[str, torch.Tensor]:
    """Mean relative depth error max(|D - z| / z - tolerance, 0) at one view's anchors where the
    render is opaque (alpha > 0.5), static and moving points each a mean of their own (a few points
    on the moving objects would weigh nothing beside thousands on the static scene). The rendered
    depth blends the camera depths of Gaussians' centres, not where the ray meets them: a flat
    Gaussian seen at a grazing angle is off by a share of its size, which `tolerance` forgives.
    camera: the render's (downscaled, cropped) camera; depth, alpha (H, W) its rasterizer output.
    moving=False: static anchors only. -> {"static": loss, "moving": loss}, a group without anchors
    in the render left out."""
    idx = anchors.by_view.get(frame_path)
    if idx is None or len(idx) == 0:
        return {}
    if not moving:
        idx = idx[~anchors.moving[idx]]
    u, v, z, ok = project(camera, anchors.points[idx])
    uu, vv = u.clamp(0, camera.width - 1), v.clamp(0, camera.height - 1)
    ok &= alpha.detach()[vv, uu] > 0.5
    err = ((depth[vv, uu] - z).abs() / z.clamp_min(1e-6) - tolerance).clamp_min(0.0)
    groups = anchors.moving[idx]
    parts = {"static": ok & ~groups, "moving": ok & groups}
    return {name: err[part].mean() for name, part in parts.items() if bool(part.any())}
