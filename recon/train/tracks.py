"""2D tracks of the rigid bodies' points from optical flow in the thermal training frames
(`PriorConfig.flow_tracks`).

One view per instant pins a body across the image but not along the ray, and the photometric loss
pulls a body only where it already overlaps its object: a body that lost its object by a few of its
own widths stays lost, and the window loss at intake prefers wrong places while the shapes are
immature (docs/training.md, "Blobs in the body search"). Optical flow between consecutive thermal
frames follows a hot object without the model: chained from the object's centre it stayed within
0.4-5.2 px over 8-39 of 39 steps on the development seeds (bench/results/flow-tracks).

A body's initial points are often floor under its object's path, whose flow is smooth,
self-consistent and wrong. So the tracks start at the hot pixels near each body in the thermal
frame at the instant the bodies were seen (the window's centre), each a point of its body at the
body's depth, and are chained forward and backward through the thermal training frames; a track ends
where the forward and backward flow disagree by more than `fb` px or it leaves the frame. Tracks
that a static point somewhere on their pixel's ray explains (a hot cup, a warm spot) are dropped.
While training, each tracked point moved by its body's motion (gate 1: the point is the body's)
must project onto its track at the window's steps; at intake a body starts where its tracks say.
Depth along the ray is left to the bodies' smoothness, as before: over several steps the camera's
motion triangulates it from the tracks.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from recon.dtg.motion import MotionBases, body_transforms, rigid_transforms


@dataclass
class Tracks:
    """M tracked points over the scene's T time steps.

    points (M, 3): canonical positions (before the bodies' motion); basis (M,) long, 1-based body;
    times (T,) the steps; viewmats (T, 4, 4) and intrinsics (T, 4) (fx, fy, cx, cy) of the thermal
    frame tracked at each step; uv (T, M, 2) the track in pixels; valid (T, M) bool."""
    points: torch.Tensor
    basis: torch.Tensor
    times: list[float]
    viewmats: torch.Tensor
    intrinsics: torch.Tensor
    uv: torch.Tensor
    valid: torch.Tensor

    def step_of(self, t: float) -> int:
        """Index of the step nearest time t."""
        return int(np.argmin(np.abs(np.asarray(self.times) - t)))


def frame_u8(scene, view) -> np.ndarray:
    """A thermal frame as 8-bit grey for optical flow: its own 1st-99.5th percentile range, so a
    heating or cooling scene keeps its contrast."""
    x, _ = scene.target(view)
    x = x.numpy()
    lo, hi = np.percentile(x, 1), np.percentile(x, 99.5)
    return (np.clip((x - lo) / max(hi - lo, 1e-6), 0, 1) * 255).astype(np.uint8)


def bilinear(field: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """field (H, W, 2) sampled at uv (M, 2) pixels (clamped to the image) -> (M, 2)."""
    h, w = field.shape[:2]
    x = np.clip(uv[:, 0], 0, w - 1.001)
    y = np.clip(uv[:, 1], 0, h - 1.001)
    x0, y0 = x.astype(int), y.astype(int)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    return (field[y0, x0] * (1 - ax) * (1 - ay) + field[y0, x0 + 1] * ax * (1 - ay)
            + field[y0 + 1, x0] * (1 - ax) * ay + field[y0 + 1, x0 + 1] * ax * ay)


def chain_flow(frames: list[np.ndarray], start: np.ndarray, k0: int, fb: float) -> tuple[np.ndarray, np.ndarray]:
    """Tracks of points at pixels start (M, 2) in frames[k0], chained with DIS flow (OpenCV, preset
    medium) to every other frame (T of them, (H, W) uint8). A track ends where the backward flow
    misses its point by more than fb px or it leaves the image. -> (uv (T, M, 2), valid (T, M))."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    t, m = len(frames), len(start)
    h, w = frames[0].shape
    uv = np.zeros((t, m, 2), np.float32)
    valid = np.zeros((t, m), bool)
    inside = lambda p: (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)   # noqa: E731
    uv[k0], valid[k0] = start, inside(start)
    for direction in (1, -1):
        p, alive, i = start.astype(np.float32), valid[k0].copy(), k0
        while alive.any() and 0 <= i + direction < t:
            j = i + direction
            q = p + bilinear(dis.calc(frames[i], frames[j], None), p)
            back = q + bilinear(dis.calc(frames[j], frames[i], None), q)
            alive &= (np.linalg.norm(back - p, axis=1) <= fb) & inside(q)
            uv[j], valid[j] = q, alive
            p, i = q, j
    return uv, valid


def project(viewmat: torch.Tensor, intrinsics: torch.Tensor, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixels of points xyz (..., M, 3) in cameras viewmat (..., 4, 4), intrinsics (..., 4):
    (uv (..., M, 2), camera depth (..., M))."""
    pc = xyz @ viewmat[..., :3, :3].transpose(-1, -2) + viewmat[..., None, :3, 3]
    z = pc[..., 2]
    fx, fy, cx, cy = (intrinsics[..., i, None] for i in range(4))
    uv = torch.stack([fx * pc[..., 0] / z.clamp_min(1e-6) + cx, fy * pc[..., 1] / z.clamp_min(1e-6) + cy], -1)
    return uv, z


def moved_points(motion: MotionBases, points: torch.Tensor, basis: torch.Tensor, t: float) -> torch.Tensor:
    """points (M, 3) moved all the way by their bodies basis (M,) (1-based) at time t -> (M, 3)."""
    per = body_transforms(motion, t).index_select(0, basis - 1)           # (M, 28)
    return torch.bmm(per[:, :9].view(-1, 3, 3), points[:, :, None])[:, :, 0] + per[:, 9:12]


def hot_pixels(scene, view, min_kelvin: float, border: int = 2) -> torch.Tensor:
    """(P, 2) pixel centres (u, v) of view's thermal frame at least min_kelvin above its median
    temperature, off its border: what optical flow follows well."""
    frame, ok = scene.target(view)
    kelvin = scene.kelvin(frame)
    floor = float(kelvin[ok].median()) if ok.any() else float(kelvin.median())
    hot = (kelvin >= floor + min_kelvin) & ok
    hot[:border], hot[-border:], hot[:, :border], hot[:, -border:] = False, False, False, False
    v, u = hot.nonzero(as_tuple=True)
    return torch.stack([u, v], 1).float() + 0.5


def back_project(viewmat: torch.Tensor, intrinsics: torch.Tensor, uv: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """World points (M, 3) at camera depth depth (M,) behind pixels uv (M, 2)."""
    fx, fy, cx, cy = intrinsics.tolist()
    pc = torch.stack([(uv[:, 0] - cx) / fx * depth, (uv[:, 1] - cy) / fy * depth, depth], 1)
    return (pc - viewmat[:3, 3]) @ viewmat[:3, :3]


@torch.no_grad()
def body_tracks(scene, model, t0: float, fb: float = 1.0, min_motion_px: float = 8.0, min_kelvin: float = 10.0,
                reach_px: float = 12.0, per_body: int = 64, gen: torch.Generator | None = None,
                log=print) -> Tracks | None:
    """Flow tracks of the hot pixels near each body in the thermal training frame nearest t0.

    A body's initial points are often floor under its object's path, and a floor's flow is smooth,
    self-consistent and wrong: so the tracks start at the frame's hot pixels (min_kelvin above its
    median) instead, each given to the body whose Gaussians project nearest, within reach_px, and
    placed at that body's median camera depth (up to per_body of them per body). Each becomes a
    point of its body (canonical: its body's motion at t0 undone). Tracks that a static point at
    some depth on their pixel's ray follows within min_motion_px (median over the steps) are
    dropped (a hot cup, a warm spot on the floor). None when there are no bodies, no thermal training frames or nothing to track."""
    motion = model.motion
    if motion is None or motion.count == 0 or not scene.train["thermal"]:
        return None
    times = [t for t in scene.times if scene.views_at("thermal", t)]
    if len(times) < 2:
        return None
    views = [scene.views_at("thermal", t)[0] for t in times]
    viewmats = torch.stack([v.camera.viewmat[:4, :4].float() for v in views])
    intrinsics = torch.tensor([[v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy] for v in views], dtype=torch.float32)
    k0 = int(np.argmin(np.abs(np.asarray(times) - t0)))
    g = model.gaussians
    members = (g["motion_basis"] > 0).nonzero()[:, 0]
    body = g["motion_basis"][members].long()
    at_t0 = moved_points(motion, g["means"][members].detach().float(), body, times[k0])
    member_uv, member_z = project(viewmats[k0], intrinsics[k0], at_t0)
    seen = member_z > 1e-3
    member_uv, member_z, body = member_uv[seen], member_z[seen], body[seen]
    pixels = hot_pixels(scene, views[k0], min_kelvin)
    if len(pixels) == 0 or len(body) == 0:
        return None
    near, which = torch.cdist(pixels, member_uv).min(1)
    owner = torch.where(near <= reach_px, body[which], torch.zeros_like(which))
    starts, bodies, depths = [], [], []
    for b in range(1, motion.count + 1):
        mine = (owner == b).nonzero()[:, 0]
        if len(mine) == 0:
            continue
        if len(mine) > per_body:
            mine = mine[torch.randperm(len(mine), generator=gen)[:per_body]]
        starts.append(pixels[mine])
        bodies.append(torch.full((len(mine),), b))
        depths.append(torch.full((len(mine),), float(member_z[body == b].median())))
    if not starts:
        return None
    start, basis, depth = torch.cat(starts), torch.cat(bodies), torch.cat(depths)
    at_t0 = back_project(viewmats[k0], intrinsics[k0], start, depth)
    # canonical: undo each body's motion at t0 (x = R p + c  ->  p = R^T (x - c))
    per = body_transforms(motion, times[k0]).index_select(0, basis - 1)
    points = torch.bmm(per[:, :9].view(-1, 3, 3).transpose(1, 2), (at_t0 - per[:, 9:12])[:, :, None])[:, :, 0]
    uv, valid = chain_flow([frame_u8(scene, v) for v in views], start.numpy(), k0, fb)
    uv, valid = torch.from_numpy(uv), torch.from_numpy(valid)
    # moving or not: whether any static point on the ray explains the track (a static hot cup does,
    # whatever its depth; a moving object does not). Median over the steps: chained flow drifts.
    off = torch.full((len(start),), torch.inf)
    for scale in torch.logspace(np.log10(0.3), np.log10(3.0), 25).tolist():
        point = back_project(viewmats[k0], intrinsics[k0], start, depth * scale)
        static, zs = project(viewmats, intrinsics, point.expand(len(times), -1, -1))     # (T, M, 2)
        err = torch.where(valid & (zs > 1e-3), (uv - static).norm(dim=-1), torch.nan)
        off = torch.minimum(off, torch.nanmedian(err, 0).values.nan_to_num(torch.inf))
    keep = off > min_motion_px
    tracked = int(keep.sum())
    log(f"flow tracks: {tracked} hot pixels near {len(set(basis[keep].tolist()))} of {motion.count} bodies move "
        f"in the thermal frames (tracked over a median "
        f"{float(valid[:, keep].sum(0).float().median()) if tracked else 0:.0f} of {len(times)} steps)")
    if tracked == 0:
        return None
    return Tracks(points[keep], basis[keep], times, viewmats, intrinsics, uv[:, keep], valid[:, keep])


def moved_at(motion: MotionBases, points: torch.Tensor, basis: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
    """points (P, 3) moved all the way by their bodies basis (P,) (1-based), each at its own time
    times (P,) (knots interpolated linearly, as MotionBases.at) -> (P, 3): every step in one pass."""
    knots = motion.rotation.shape[1]
    x = times.clamp(0, 1) * (knots - 1)
    i0 = x.floor().long().clamp(max=knots - 1)
    i1 = (i0 + 1).clamp(max=knots - 1)
    w = (x - i0)[:, None]
    b = basis - 1
    rot = torch.lerp(motion.rotation[b, i0], motion.rotation[b, i1], w)
    trans = torch.lerp(motion.translation[b, i0], motion.translation[b, i1], w)
    per = rigid_transforms(rot, trans, motion.pivots[b])
    return torch.bmm(per[:, :9].view(-1, 3, 3), points[:, :, None])[:, :, 0] + per[:, 9:12]


def track_loss(motion: MotionBases, tracks: Tracks, steps: torch.Tensor, delta_px: float = 2.0) -> torch.Tensor:
    """Mean Huber distance (in units of delta_px: quadratic within it, linear beyond) between the
    tracked points moved by their bodies and their tracks, over steps (S,) (indices into
    tracks.times: the window's) where a track is valid. Only the bodies' motion gets gradients."""
    step, point = tracks.valid[steps].nonzero(as_tuple=True)
    if len(step) == 0:
        return motion.translation.sum() * 0
    k = steps[step]
    times = torch.tensor(tracks.times, dtype=torch.float32)[k]
    xyz = moved_at(motion, tracks.points[point], tracks.basis[point], times)
    vm = tracks.viewmats[k]
    pc = torch.bmm(vm[:, :3, :3], xyz[:, :, None])[:, :, 0] + vm[:, :3, 3]
    fx, fy, cx, cy = tracks.intrinsics[k].unbind(1)
    z = pc[:, 2].clamp_min(1e-6)
    uv = torch.stack([fx * pc[:, 0] / z + cx, fy * pc[:, 1] / z + cy], 1)
    r = (uv - tracks.uv[k, point]).norm(dim=-1) / delta_px
    return torch.where(r < 1, r * r, 2 * r - 1).mean()


@torch.no_grad()
def track_offset(motion: MotionBases, tracks: Tracks, b: int, t: float, min_points: int = 3) -> torch.Tensor | None:
    """(3,) world offset that moves body b (0-based) at time t across the tracked frame's image
    plane, at its points' depth, so that its tracked points land on their tracks (median pixel
    shift over the points); None with fewer than min_points valid tracks there."""
    k = tracks.step_of(t)
    ok = tracks.valid[k] & (tracks.basis == b + 1)
    if int(ok.sum()) < min_points:
        return None
    xyz = moved_points(motion, tracks.points[ok], tracks.basis[ok], t)
    uv, z = project(tracks.viewmats[k], tracks.intrinsics[k], xyz)
    du, dv = (tracks.uv[k, ok] - uv).median(0).values.tolist()
    depth = float(z.median())
    if depth <= 1e-3:
        return None
    fx, fy = float(tracks.intrinsics[k, 0]), float(tracks.intrinsics[k, 1])
    rot = tracks.viewmats[k, :3, :3]
    return (du * depth / fx) * rot[0] + (dv * depth / fy) * rot[1]
