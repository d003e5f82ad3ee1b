"""A time window that grows from one instant: motion learned as tracking, one step at a time.

Photometric gradients only pull a Gaussian towards an object it already overlaps on screen. A
moving object of the scene family travels 5-20 times its own size over a capture, so a motion
model fitted on every time step at once finds no gradient that carries the object's Gaussians
from where they were initialised to where it is seen at most instants, and smears it instead.
Between two neighbouring time steps the same object moves a fraction of its size. So training
starts on the time steps around ``center`` and the window grows by one time step on each side
every ``grow_every`` iterations; time steps beyond the window carry the motion of its edge on at
constant velocity (``extrapolate_rows``), which puts them where the next step will most likely
find the object.
"""
from __future__ import annotations

import torch

from recon.dtg.motion import apply_motion
from recon.render import render_frame
from recon.train.resolution import downscale


def window_bounds(iteration: int, n_times: int, center: float, start_steps: int, grow_every: float,
                  hold: float = 0) -> tuple[int, int]:
    """(lo, hi) inclusive indices into the sorted training times that are trained at `iteration`:
    `start_steps` on each side of `center` for `hold` iterations, then one more every `grow_every`."""
    if grow_every <= 0:
        return 0, n_times - 1
    mid = round(center * (n_times - 1))
    half = start_steps + int(max(iteration - hold, 0) / grow_every)
    return max(mid - half, 0), min(mid + half, n_times - 1)


class TimeWindow:
    """The time steps training may draw from, growing with the iteration count (window_bounds).

    times: the scene's sorted time steps. ``update(iteration)`` moves the window and returns the
    edges it took in since the last call as [("lo" | "hi", time)]; ``pick`` draws a training time:
    with probability ``edge_weight`` one of the window's open edges (the steps whose motion is
    least fitted), with probability ``outside`` a step beyond the window (trained with a trimmed
    loss: it teaches the static scene), else uniformly inside."""

    def __init__(self, cfg, times: list[float], iterations: int | None = None):
        self.cfg, self.times = cfg, list(times)
        self.bounds: tuple[int, int] | None = None
        # a short run keeps the shape of the schedule: the window is whole by `complete_by` of it
        self.hold, self.grow_every = float(cfg.hold), float(cfg.grow_every)
        if iterations and self.enabled:
            mid = round((cfg.center if cfg.center >= 0 else 0.5) * (len(self.times) - 1))
            steps = max(mid, len(self.times) - 1 - mid) - cfg.start_steps
            self.hold = min(self.hold, 0.1 * iterations)
            if steps > 0:
                self.grow_every = min(self.grow_every, max(cfg.complete_by * iterations - self.hold, 0) / steps)
            self.grow_every = max(self.grow_every, 1e-3)

    @property
    def enabled(self) -> bool:
        return self.cfg.grow_every > 0 and len(self.times) > 1

    @property
    def grown(self) -> bool:
        """Whether the window has taken in a step beyond its starting ones."""
        if self.bounds is None:
            return False
        mid = round((self.cfg.center if self.cfg.center >= 0 else 0.5) * (len(self.times) - 1))
        return self.bounds[1] - self.bounds[0] > min(mid + self.cfg.start_steps, len(self.times) - 1) - max(mid - self.cfg.start_steps, 0)

    @property
    def complete(self) -> bool:
        return not self.enabled or self.bounds == (0, len(self.times) - 1)

    def span(self) -> tuple[float, float]:
        lo, hi = self.bounds or (0, len(self.times) - 1)
        return self.times[lo], self.times[hi]

    def contains(self, t: float) -> bool:
        lo, hi = self.span()
        return lo <= t <= hi

    def update(self, iteration: int) -> list[tuple[str, float]]:
        if not self.enabled:
            return []
        c = self.cfg
        bounds = window_bounds(iteration, len(self.times), c.center if c.center >= 0 else 0.5, c.start_steps,
                               self.grow_every, self.hold)
        before, self.bounds = self.bounds, bounds
        if before is None or before == bounds:
            return []
        return ([("lo", self.times[bounds[0]])] if bounds[0] != before[0] else []) + \
               ([("hi", self.times[bounds[1]])] if bounds[1] != before[1] else [])

    def pick(self, train_times: list[float], generator: torch.Generator) -> float:
        """A training time step (train_times: the steps training may use, sorted)."""
        def draw(options):
            return options[int(torch.randint(len(options), (1,), generator=generator))]
        if self.complete:
            return draw(train_times)
        lo, hi = self.span()
        inside = [t for t in train_times if lo <= t <= hi] or [min(train_times, key=lambda t: abs(t - lo))]
        outside = [t for t in train_times if not lo <= t <= hi]
        edges = ([inside[0]] if lo > self.times[0] else []) + ([inside[-1]] if hi < self.times[-1] else [])
        u = float(torch.rand((), generator=generator))
        if outside and u < self.cfg.outside:
            return draw(outside)
        if edges and u < self.cfg.outside + self.cfg.edge_weight * (1 - self.cfg.outside):
            return draw(edges)
        return draw(inside)


@torch.no_grad()
def extrapolate_rows(table: torch.Tensor, lo: float, hi: float, dim: int = 0, velocity: bool = True) -> None:
    """In place: rows of `table` along `dim` (row r at time r / (R - 1)) lying before time lo or
    after time hi become the edge row continued at the edge's velocity (velocity=False: a copy of
    the edge row). (R, D) or with dim=1 (N, R, C)."""
    rows = table.shape[dim]
    if rows < 2:
        return
    x_lo, x_hi = lo * (rows - 1), hi * (rows - 1)
    first = int(torch.tensor(x_lo).ceil())          # first row inside the window
    last = int(torch.tensor(x_hi).floor())          # last row inside the window
    t = table.movedim(dim, 0)
    if last < rows - 1 and last >= 0:
        edge = t[last].clone()
        step = (edge - t[last - 1]) if velocity and last >= 1 and last - 1 >= first else torch.zeros_like(edge)
        for r in range(last + 1, rows):
            t[r] = edge + (r - last) * step
    if first > 0 and first <= rows - 1:
        edge = t[first].clone()
        step = (edge - t[first + 1]) if velocity and first + 1 <= rows - 1 and first + 1 <= last else torch.zeros_like(edge)
        for r in range(first - 1, -1, -1):
            t[r] = edge + (first - r) * step


@torch.no_grad()
def continue_beyond(model, lo: float, hi: float) -> None:
    """The model's time rows beyond the window [lo, hi] continue its edges: trajectory and motion
    knots at constant velocity, time-embedding rows held (extrapolate_rows)."""
    if model.cfg.deformation == "none":
        return
    g = model.gaussians
    if "trajectory" in g:
        extrapolate_rows(g["trajectory"].data, lo, hi, dim=1, velocity=True)
    if model.motion is not None:
        extrapolate_rows(model.motion.rotation.data, lo, hi, dim=1, velocity=True)
        extrapolate_rows(model.motion.translation.data, lo, hi, dim=1, velocity=True)
    te = model.time_embedding
    for table in (te.coarse, te.fine):
        extrapolate_rows(table.data, lo, hi, dim=0, velocity=False)


SEARCH_WIDTH = 160     # place_bases compares views about this wide: its pixel steps were chosen there


def frames_at(scene, modalities, t: float) -> list[tuple]:
    """[(modality, camera, target, valid)] of every training view at time t, downscaled to about
    SEARCH_WIDTH pixels wide: what place_bases compares (at 640x480 its renders at full size
    made a run's first minutes 10x slower)."""
    frames = []
    for m in modalities:
        for view in scene.views_at(m, t):
            target, valid = scene.target(view)
            camera, target, valid = downscale(view.camera, target, valid, max(1, view.camera.width // SEARCH_WIDTH))
            frames.append((m, camera, target, valid))
    return frames


def frame_loss(model, frames, t: float) -> float:
    """Mean L1 of the model's renders at time t against frames [(modality, camera, target, valid)]."""
    total = 0.0
    for modality, camera, target, valid in frames:
        pred = render_frame(model, modality, t, camera)
        if modality == "rgb":
            total += float((pred - target).abs().mean())
        else:
            err = (pred[..., 0] - target).abs()
            total += float(err[valid].mean()) if valid is not None and valid.any() else float(err.mean())
    return total / max(len(frames), 1)


@torch.no_grad()
def place_bases(model, frames, t: float, side: str, min_opacity_mass: float = 1.0,
                pixel_steps: tuple[float, ...] = (6.0, 3.0)) -> None:
    """Where each motion basis is at a time step the window just took in: a coarse search before
    the gradient refines it. The knots of the new step (and beyond, on `side` 'lo' or 'hi') start
    at constant velocity; for each basis with Gaussians near the view, offsets of (pixel_steps)
    pixels across the first frame's image plane (a 3x3 grid per step size, best kept) are tried,
    and the one with the lowest loss over `frames` (the views at t) is kept. Depth is left to the
    trajectory smoothness (MotionBases.smoothness): one view pins it poorly. Photometric gradients
    only pull an object that already overlaps its image; a search finds one that the
    constant-velocity guess missed by a few pixels."""
    motion = model.motion
    if motion is None or not frames or motion.count == 0:
        return
    g = model.gaussians
    knots = motion.translation.shape[1]
    x = t * (knots - 1)
    rows = torch.arange(knots)
    rows = rows[rows >= round(x)] if side == "hi" else rows[rows <= round(x)]
    basis = g["motion_basis"].long()
    gate = model.dynamic_gate()
    weight = torch.sigmoid(g[f"opacity_{frames[0][0]}"]) * gate
    cam = frames[0][1]
    rot = cam.viewmat[:3, :3]
    current = frame_loss(model, frames, t)
    for b in range(motion.count):
        sel = basis == b + 1
        if float(weight[sel].sum()) < min_opacity_mass:
            continue
        means, _ = apply_motion(g["means"][sel], g["quats"][sel], g["motion_basis"][sel], gate[sel], motion, t)
        pc = means @ rot.T + cam.viewmat[:3, 3]
        u = cam.fx * pc[:, 0] / pc[:, 2].clamp_min(1e-6) + cam.cx
        v = cam.fy * pc[:, 1] / pc[:, 2].clamp_min(1e-6) + cam.cy
        margin = 0.25 * cam.width
        near = (pc[:, 2] > 1e-3) & (u > -margin) & (u < cam.width + margin) & (v > -margin) & (v < cam.height + margin)
        w = weight[sel] * near
        if float(w.sum()) < min_opacity_mass:     # nothing of it near this view: nothing to search
            continue
        centre = (means * w[:, None]).sum(0) / w.sum()
        depth = float(rot[2] @ centre + cam.viewmat[2, 3])
        if depth <= 1e-3:
            continue
        # a fast object may be further off its constant-velocity guess: steps grow with its speed
        k = int(rows[0]) if side == "hi" else int(rows[-1])
        k_prev = k - 1 if side == "hi" else k + 1
        speed = 0.0
        if 0 <= k_prev < knots:
            speed = float((motion.translation[b, k] - motion.translation[b, k_prev]).norm()) * cam.fx / depth
        steps = [max(s, 0.5 ** i * 0.5 * speed) for i, s in enumerate(pixel_steps)]
        candidates = [[(i * s * depth / cam.fx) * rot[0] + (j * s * depth / cam.fy) * rot[1]
                       for i in (-1, 0, 1) for j in (-1, 0, 1)] for s in steps]
        for group in candidates:
            best, best_loss = torch.zeros(3), current
            for offset in group:
                if not offset.abs().sum():
                    continue
                motion.translation.data[b, rows] += offset
                loss = frame_loss(model, frames, t)
                motion.translation.data[b, rows] -= offset
                if loss < best_loss - 1e-6:
                    best, best_loss = offset, loss
            if best.abs().sum():
                motion.translation.data[b, rows] += best
                current = best_loss
