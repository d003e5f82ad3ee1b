"""Which initial points are moving bodies, found after a static warm-up.

The initial points of a dynamic scene hold moving objects where some frame saw them (an SfM cloud,
or a simulator's frames sampled at several instants: ghosts along each path), and telling them
from the scene around them by colour alone fails: a floor point on an object's path also reads
changing colours (the object passes over it), and an object with the floor's colour reads none.
Once a static model of the scene exists (trained on every frame with a trimmed loss, so moving
objects are left out), a point is on a moving object at time t where

- the frames at t differ from the static render all around the point's projection (a 3x3
  neighbourhood: what is there now is not the static scene; edges of a blurry static model are
  not), in RGB where the point's own colour is seen there, or in temperature, and
- the point lies in front of the static surface there (a floor point under a passing object lies
  on it; a point of the object recorded at another instant floats in front of the surface too, but
  what is there at t is the static scene or not its colour).

The time step where most points pass is where the bodies are built (``center``); each spatially
connected group of the points passing there is one rigid body (recon/dtg/motion.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from recon.dtg.motion import body_clusters
from recon.dtg.points import colour_distance, project
from recon.render import render_frame_layers
from recon.scene import Scene


@dataclass(frozen=True)
class DiscoverSettings:
    rgb_residual: float = 0.15        # max-channel |frame - static render| that counts as not static
    kelvin_residual: float = 4.0      # |frame - static render| in kelvin likewise
    in_front: float = 0.04            # a point must be this fraction of the depth nearer than the surface
    colour_tolerance: float = 0.1     # its colour as seen (max over channels, 3x3 neighbourhood)
    free_space: float = 0.3           # fraction of the steps that must see through a point
    near_steps: float = 3.0           # a point's steps on an object must centre this close to the bodies' step
    min_points: int = 3               # a body has at least this many points
    max_bodies: int = 32


@dataclass
class Bodies:
    center: float                      # the time step the bodies are built at
    members: list[torch.Tensor]        # per body, indices into the candidate points
    on_counts: list[int]               # candidate points on a moving object, per time step


@torch.no_grad()
def on_moving_object(model, scene: Scene, points: torch.Tensor, colors: torch.Tensor,
                     settings: DiscoverSettings) -> torch.Tensor:
    """(T, M) bool over scene.times: point m (points (M, 3), colors (M, 3) in [0, 1]) is on a moving
    object at time step t. A point counts only if at other time steps the frames see through it:
    the static render explains them there, while the point floats in front of the static surface
    (in at least `free_space` of the steps that see it): the object has left. A point on the
    static scene (an edge the blurry static model puts too far back) is seen on its surface."""
    span = scene.k_max - scene.k_min
    out = torch.zeros(len(scene.times), len(points), dtype=torch.bool)
    free = torch.zeros(len(points))
    seen = torch.zeros(len(points))
    # temperature is the cleaner witness (a static thermal model fits to ~0.1 K where the RGB one
    # is still blurred to ~0.05 of its range after a short warm-up)
    see_through = "thermal" if "thermal" in model.cfg.modalities else model.cfg.modalities[0]
    for i, t in enumerate(scene.times):
        for modality in model.cfg.modalities:
            limit = settings.rgb_residual if modality == "rgb" else settings.kelvin_residual / span
            for view in scene.views_at(modality, t):
                image, depth, alpha = render_frame_layers(model, modality, t, view.camera)
                target, valid = scene.target(view)
                target = target if target.dim() == 3 else target[..., None]
                residual = (image - target).abs().amax(-1)
                if valid is not None:
                    residual = torch.where(valid, residual, torch.nan)
                moved = -F.max_pool2d(-(residual > limit)[None, None].float(), 3, 1, 1)[0, 0] > 0.5  # all 9 px
                still = F.max_pool2d((residual > 0.5 * limit)[None, None].float(), 3, 1, 1)[0, 0] < 0.5  # none
                cam = view.camera
                u, v, z, ok = project(cam, points)
                uu, vv = u.clamp(0, cam.width - 1), v.clamp(0, cam.height - 1)
                surface = torch.where(alpha[vv, uu] > 0.5, depth[vv, uu], torch.inf)
                front = ok & (z < surface * (1 - settings.in_front))
                hit = front & moved[vv, uu]
                if modality == see_through:
                    free += (front & still[vv, uu]).float()
                    seen += ok.float()
                if modality == "rgb":
                    hit &= colour_distance(target, u, v, colors) < settings.colour_tolerance
                out[i] |= hit
    return out & (free >= settings.free_space * seen.clamp_min(1))[None]


def group_bodies(points: torch.Tensor, on: torch.Tensor, times: list[float],
                 settings: DiscoverSettings) -> Bodies | None:
    """The time step with the most points on moving objects, and the bodies there: connected
    groups (linked within 3x their median nearest-neighbour spacing) of the points on an object
    at that step and recorded near it: the middle of the steps a point is on an object is within
    `settings.near_steps` of it (a point recorded at another instant can still lie inside the
    object for a few steps, or where its path crosses back)."""
    steps = torch.arange(len(times), dtype=torch.float32)[:, None]
    count = on.sum(0)
    middle = (on * steps).sum(0) / count.clamp_min(1)
    near = lambda i: on[i] & ((middle - i).abs() <= settings.near_steps)  # noqa: E731
    counts = torch.stack([near(i).sum() for i in range(len(times))])
    if int(counts.max()) < settings.min_points:
        return None
    # most points; among equals the middle of the sequence (motion is learned outwards from it)
    mid = (len(times) - 1) / 2
    best = max(range(len(times)), key=lambda i: (int(counts[i]), -abs(i - mid)))
    index = near(best).nonzero()[:, 0]
    members = [index[b] for b in body_clusters(points[index], settings.min_points, settings.max_bodies)]
    if not members:
        return None
    return Bodies(times[best], members, [int(c) for c in counts])
