"""The model a run starts from: Gaussians at the dataset's SfM points, their temperatures read from
the thermal views, learned backgrounds started from the image borders, and (dtg) the rigid bodies:
on the moving objects' paths that the thermal frames give (recon/train/paths.py), else found among
the points that see the scene change (recon/dtg/motion.py)."""
from __future__ import annotations

import numpy as np
import torch

from recon.config import TrainConfig
from recon.dtg.gaussians import init_gaussians, trajectory_knots
from recon.dtg.model import DTGModel
from recon.dtg.motion import body_clusters, body_radii
from recon.dtg.points import (changing_points, colour_seen_fraction, initial_temperatures, observed_time,
                               seen_mean, transient_points)
from recon.scene import Scene
from recon.train.anchors import DepthAnchors, find_anchors
from recon.train.paths import TrackedPath, on_still_blobs, tracked_paths
from recon.sfm import interpolated_points, points_from_frames


def initial_background(scene: Scene, modality: str) -> torch.Tensor:
    """Median of the image borders over a few training views: a start for the learned background."""
    views = scene.train[modality][:: max(1, len(scene.train[modality]) // 4)][:4]
    border = []
    for view in views:
        img, valid = scene.target(view)
        img = img if img.dim() == 3 else img[..., None]
        ring = torch.cat([img[0], img[-1], img[:, 0], img[:, -1]])
        if valid is not None:
            ring = ring[torch.cat([valid[0], valid[-1], valid[:, 0], valid[:, -1]])]
        border.append(ring)
    return torch.cat(border).median(0).values if border else torch.zeros(3 if modality == "rgb" else 1)


def initial_points(cfg: TrainConfig, scene: Scene, gen: torch.Generator, log=print) -> tuple[torch.Tensor, torch.Tensor]:
    """The dataset's initial points (at most cfg.max_points of them): (xyz (P, 3), rgb (P, 3) in [0, 1]).
    A dataset without points3d.ply gets them triangulated from its RGB frames with its poses, and
    interpolated over the surfaces between them (recon/sfm.py)."""
    ds = scene.dataset
    if ds.points_xyz is None or len(ds.points_xyz) == 0:
        log(f"{ds.root}: no initial points (points3d.ply): triangulating them from the RGB frames (SfM)")
        xyz, rgb = points_from_frames(ds)
        more_xyz, more_rgb = interpolated_points(ds, xyz)
        ds.points_xyz, ds.points_rgb = np.concatenate([xyz, more_xyz]), np.concatenate([rgb, more_rgb])
        log(f"{len(xyz)} points triangulated, {len(more_xyz)} more interpolated between them")
    pts = torch.as_tensor(np.asarray(ds.points_xyz), dtype=torch.float32)
    rgb = torch.as_tensor(np.asarray(ds.points_rgb if ds.points_rgb is not None else np.full((len(pts), 3), 0.5)),
                          dtype=torch.float32)
    if rgb.max() > 1.0:
        rgb = rgb / 255.0
    if len(pts) > cfg.max_points:
        keep = torch.randperm(len(pts), generator=gen)[: cfg.max_points]
        pts, rgb = pts[keep], rgb[keep]
    return pts, rgb


def warm_up_iterations(cfg: TrainConfig) -> int:
    """Iterations of the static warm-up before body discovery (at most 15 % of the run); 0: the
    bodies come from the initial points at the start."""
    m = cfg.model
    if not (m.motion_bases and m.deformation != "none" and cfg.curriculum.discover_after > 0):
        return 0
    return max(1, min(cfg.curriculum.discover_after, int(0.15 * cfg.iterations)))


def body_candidates(cfg: TrainConfig, scene: Scene, pts: torch.Tensor, rgb: torch.Tensor) -> torch.Tensor:
    """(P,) bool: initial points that may lie on moving objects (the scene changes where they
    project, or their own colour is seen only now and then): held out of the static warm-up."""
    m = cfg.model
    return changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction) | transient_points(scene, pts, rgb)


def depth_anchors(cfg: TrainConfig, scene: Scene) -> DepthAnchors | None:
    """The initial points as depth anchors of the RGB training views (recon/train/anchors.py),
    or None when both LossConfig.point_depth weights are 0 or there are no RGB training views. The points are
    initial_model's (same seed), before any are held out or dropped as ghosts."""
    if max(cfg.loss.point_depth_static, cfg.loss.point_depth_moving) <= 0 or not scene.train["rgb"]:
        return None
    pts, rgb = initial_points(cfg, scene, torch.Generator().manual_seed(cfg.seed))
    m = cfg.model
    changing = changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction)
    return find_anchors(scene, pts, rgb, changing)


def held_points(cfg: TrainConfig, scene: Scene) -> tuple[torch.Tensor, torch.Tensor]:
    """The candidate points initial_model held out (recomputed, as on a resumed run)."""
    pts, rgb = initial_points(cfg, scene, torch.Generator().manual_seed(cfg.seed))
    held = body_candidates(cfg, scene, pts, rgb)
    return pts[held], rgb[held]


def initial_model(cfg: TrainConfig, scene: Scene, gen: torch.Generator, log
                  ) -> tuple[DTGModel, tuple[torch.Tensor, torch.Tensor] | None]:
    """A new model from the scene's initial points, and the points held out of it for body
    discovery (recon/train/discover.py; None without). Without discovery the bodies are built on the
    paths of curriculum.tracked_paths (_tracked_bodies, which makes the window whole) or, where none
    is found, come from the points (_motion_bodies, which may set cfg.curriculum.center, when it is
    automatic, to the instant the moving points were seen)."""
    pts, rgb = initial_points(cfg, scene, gen, log)
    n_times = scene.steps_per_unit_time()
    m = cfg.model
    held = None
    bases = m.motion_bases and m.deformation != "none"
    if warm_up_iterations(cfg):
        mask = body_candidates(cfg, scene, pts, rgb)
        held = (pts[mask], rgb[mask])
        pts, rgb = pts[~mask], rgb[~mask]
        log(f"{int(mask.sum())} of {len(mask)} initial points may lie on moving objects: held out of a static "
            f"warm-up of {warm_up_iterations(cfg)} iterations, then searched for bodies")
        bases = False
    dynamic = changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction) \
        if m.motion_split or bases else None
    tracks = None
    if "thermal" in m.modalities and ((bases and cfg.curriculum.tracked_paths) or m.hold_in_place):
        tracks = tracked_paths(scene, cfg.paths)
    if dynamic is not None and m.hold_in_place and tracks is not None and tracks.still:
        in_place = on_still_blobs(scene, tracks.still, pts)     # they change temperature, not place
        log(f"{int((dynamic & in_place).sum())} initial points that see a changing scene lie on a still hot "
            f"or cold blob: they stay static")
        dynamic &= ~in_place
    if dynamic is not None:
        log(f"static/dynamic split: {int(dynamic.sum())} of {len(pts)} initial points see a "
            f"changing scene and may move")
    basis, pivots, paths = None, None, []
    if bases and cfg.curriculum.tracked_paths and tracks is not None:
        paths = tracks.moving
    if paths:
        pts, rgb, dynamic, basis, pivots = _tracked_bodies(cfg, scene, pts, rgb, dynamic, paths, log)
    elif bases:
        pts, rgb, dynamic, basis, pivots = _motion_bodies(cfg, scene, pts, rgb, dynamic, log)
    temps = initial_temperatures(scene, pts) if "thermal" in m.modalities else None
    if paths:                              # a body's temperature as seen where it was built
        fill = temps[basis == 0].median()[None] if bool((basis == 0).any()) else temps.median()[None]
        for b, path in enumerate(paths):
            rows = basis == b + 1
            temps[rows] = seen_colours(scene, "thermal", path.reference, pts[rows], fill)[:, 0]
    gates = body_gates(cfg, scene, pts, rgb, basis) if basis is not None else None
    if gates is not None:       # a body turns about what moves in it, not about the floor it came with
        for b in range(len(pivots)):
            moving = (basis == b + 1) & (gates > m.basis_gate_static)
            if int(moving.sum()) >= 3:
                pivots[b] = pts[moving].mean(0)
    params = init_gaussians(pts, rgb, temps, m, cfg.routing, gen, trajectory_knots(m, n_times),
                            dynamic if m.motion_split else None, basis, gates)
    bgs = {mod: initial_background(scene, mod) for mod in m.modalities}
    radii = body_radii(pts, basis, pivots, m.body_reach) if pivots is not None else None
    model = DTGModel(m, params, n_times=n_times, backgrounds=bgs, pivots=pivots, radii=radii)
    if paths:
        with torch.no_grad():
            knots = torch.linspace(0, 1, model.motion.translation.shape[1])
            for b, path in enumerate(paths):
                model.motion.translation[b] = path.at(knots) - pivots[b]
                model.motion.anchors[b] = model.motion.translation[b]
                model.motion.anchored[b] = (resting_knots(knots, path) if cfg.priors.path_hold_rests
                                            else measured_knots(knots, path))
                model.motion.anchor_precision[b] = knot_precision(knots, path)
    return model, held


def body_gates(cfg: TrainConfig, scene: Scene, pts: torch.Tensor, rgb: torch.Tensor, basis: torch.Tensor
               ) -> torch.Tensor | None:
    """(P,) starting gate logits of points pts (P, 3) with colours rgb (P, 3) in bodies basis (P,):
    basis_gate_static for members that look static (colour_seen_fraction >= basis_static_share),
    basis_gate_init for the others; None when ModelConfig.basis_gate_static is off."""
    m = cfg.model
    if m.basis_gate_static is None:
        return None
    gates = torch.full((len(pts),), m.basis_gate_init)
    members = basis > 0
    if members.any():
        share = colour_seen_fraction(scene, pts[members], rgb[members])
        gates[members] = torch.where(share >= m.basis_static_share, m.basis_gate_static, m.basis_gate_init)
    return gates


def body_gaussians(cfg: TrainConfig, scene: Scene, pts: torch.Tensor, rgb: torch.Tensor, basis: torch.Tensor,
                   t: float, gen: torch.Generator) -> dict[str, torch.Tensor]:
    """New Gaussians (every per-Gaussian tensor) at points (M, 3) of bodies basis (M,) (1-based),
    their temperature read from the thermal views at time t."""
    m = cfg.model
    temps = None
    if "thermal" in m.modalities:
        mean, seen = seen_mean(scene, scene.views_at("thermal", t) or scene.train["thermal"], pts)
        temps = torch.where(seen, mean[:, 0], initial_temperatures(scene, pts)).clamp(0, 1)
    return init_gaussians(pts, rgb, temps, m, cfg.routing, gen, trajectory_knots(m, scene.steps_per_unit_time()),
                          None, basis.float())


def measured_knots(knots: torch.Tensor, path: TrackedPath) -> torch.Tensor:
    """(K,) which knot times knots (K,) lie within the span of the frames path was fitted to (one
    knot's spacing either side): beyond it the path is extrapolated, not measured."""
    seen = torch.tensor(sorted(path.seen), dtype=knots.dtype)
    step = float(knots[1] - knots[0]) if len(knots) > 1 else 1.0
    return (knots >= seen[0] - step) & (knots <= seen[-1] + step)


def resting_knots(knots: torch.Tensor, path: TrackedPath) -> torch.Tensor:
    """(K,) which knot times knots (K,) lie inside one of path's rests: where the frames showed the
    object standing still, so its path there is a triangulated point, not a slide along the rays."""
    inside = torch.zeros(len(knots), dtype=torch.bool)
    for t0, t1 in path.rests:
        inside |= (knots >= t0 - 1e-6) & (knots <= t1 + 1e-6)
    return inside


def knot_precision(knots: torch.Tensor, path: TrackedPath, floor_m: float = 0.01) -> torch.Tensor:
    """(K, 3, 3) inverse covariance (1/m^2) of path's positions at knot times knots (K,), each
    covariance widened by floor_m^2 (a blob's centroid is not the object's centre, and a body's
    pivot not its centroid); zeros when the path has no covariance."""
    cov = path.covariance_at(knots.numpy())
    if cov is None:
        return torch.zeros(len(knots), 3, 3)
    return torch.as_tensor(np.linalg.inv(cov + floor_m ** 2 * np.eye(3)), dtype=torch.float32)


def sphere_points(centre: torch.Tensor, radius: float, count: int) -> torch.Tensor:
    """(count, 3) points spread evenly over a sphere (a Fibonacci lattice)."""
    i = torch.arange(count, dtype=torch.float32) + 0.5
    z = 1 - 2 * i / count
    phi = i * torch.pi * (3 - 5 ** 0.5)
    ring = (1 - z * z).clamp_min(0).sqrt()
    return centre + radius * torch.stack([ring * torch.cos(phi), ring * torch.sin(phi), z], 1)


def seen_colours(scene: Scene, modality: str, t: float, pts: torch.Tensor, default: torch.Tensor) -> torch.Tensor:
    """(M, C) what modality's views at time t see where pts (M, 3) project; points no view sees get
    the mean of those seen (default when none is)."""
    views = scene.views_at(modality, t)
    if not views:
        return default.expand(len(pts), -1).clone()
    mean, seen = seen_mean(scene, views, pts)
    fill = mean[seen].mean(0) if bool(seen.any()) else default
    return torch.where(seen[:, None], mean, fill)


def _tracked_bodies(cfg: TrainConfig, scene: Scene, pts, rgb, dynamic, paths: list[TrackedPath], log):
    """Rigid bodies on the paths the thermal frames gave (recon/train/paths.py): per path a sphere
    of Gaussians of the blob's size at the instant its blob was largest (the pivot), coloured by
    what the views at that instant see. Initial points the paths pass through (objects recorded at
    other instants) are dropped. The bodies' paths are known for the whole sequence, so the time
    window does not grow: every step trains from the start.
    -> (points, colours, dynamic flags, basis (P',), pivots (B, 3))"""
    m = cfg.model
    t = torch.linspace(0, 1, 4 * len(scene.times))
    ghost = torch.zeros(len(pts), dtype=torch.bool)
    for path in paths:
        ghost |= torch.cdist(pts, path.at(t)).amin(1) < 0.9 * path.radius
    pts, rgb, dynamic = pts[~ghost], rgb[~ghost], None if dynamic is None else dynamic[~ghost]
    count = 4 * max(m.basis_points, 32)
    pivots = torch.stack([path.at(path.reference)[0] for path in paths])
    body_pts = [sphere_points(pivots[b], path.radius, count) for b, path in enumerate(paths)]
    body_rgb = [seen_colours(scene, "rgb", path.reference, p, torch.full((3,), 0.5)) if "rgb" in m.modalities
                else torch.full((len(p), 3), 0.5) for p, path in zip(body_pts, paths)]
    basis = torch.cat([torch.zeros(len(pts))] + [torch.full((count,), b + 1.0) for b in range(len(paths))])
    if dynamic is not None:
        dynamic = torch.cat([dynamic, torch.ones(count * len(paths), dtype=torch.bool)])
    pts, rgb = torch.cat([pts] + body_pts), torch.cat([rgb] + body_rgb)
    cfg.curriculum.grow_every = 0
    log(f"motion bases: {len(paths)} rigid bodies on paths tracked in the thermal frames "
        f"({', '.join(f'r {p.radius:.2f} m, {p.frames} frames' for p in paths)}); {int(ghost.sum())} initial "
        f"points on their paths dropped; every time step trains from the start")
    return pts, rgb, dynamic, basis, pivots


def _motion_bodies(cfg: TrainConfig, scene: Scene, pts, rgb, dynamic, log):
    """Rigid bodies from the initial points: the moving points as seen at one instant, one body per
    spatially connected group of them. Points of moving things seen at other instants (ghosts
    along their paths) are dropped: from that instant on they would be in the wrong place.
    pts (P, 3), rgb (P, 3), dynamic (P,) -> (points, colours, dynamic flags, basis (P',), pivots (B, 3))"""
    m, c = cfg.model, cfg.curriculum
    flagged = dynamic.clone()
    seen = observed_time(scene, pts[flagged], rgb[flagged]) if flagged.any() else None
    if seen is not None:
        t_seen, matched = seen
        if c.center < 0:
            c.center = t_seen
            log(f"the moving points match the views best at t = {t_seen:.3f}: motion is learned "
                f"outwards from there")
        ghosts = flagged.nonzero()[:, 0][~matched]
        keep = torch.ones(len(pts), dtype=torch.bool)
        keep[ghosts] = False
        pts, rgb, dynamic, flagged = pts[keep], rgb[keep], dynamic[keep], flagged[keep]
        log(f"{len(ghosts)} moving points seen at other instants dropped")
    basis = torch.zeros(len(pts))
    index = flagged.nonzero()[:, 0]
    smallest = max(m.basis_points // 5, 3)
    if len(index) < smallest:
        log("motion bases: no moving points; every Gaussian is static")
        return pts, rgb, dynamic, basis, torch.zeros(0, 3)
    bodies = body_clusters(pts[index], smallest, m.motion_bases)
    if not bodies:
        log("motion bases: the moving points form no body; every Gaussian is static")
        return pts, rgb, dynamic, basis, torch.zeros(0, 3)
    pivots = torch.stack([pts[index[members]].mean(0) for members in bodies])
    for b, members in enumerate(bodies):
        basis[index[members]] = b + 1
    log(f"motion bases: {len(bodies)} rigid bodies from {int((basis > 0).sum())} moving points")
    return pts, rgb, dynamic, basis, pivots
