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

from contextlib import contextmanager

import torch

from recon.dtg.motion import apply_motion
from recon.render import draw, inference_masks, pixel_boxes, render_frame
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


@torch.no_grad()
def window_loss(model, frames, t: float, windows: list | None = None, inputs: list | None = None) -> float:
    """Mean L1 of the model's renders at time t against frames [(modality, camera, target, valid)]
    (thermal over valid pixels), each frame's error summed over one pixel window only: windows
    [(x0, y0, w, h) | None (the whole frame) | () (skip the frame)], None: whole frames. A window's
    error is divided by its whole frame's pixel count, so when only the pixels inside the windows
    can change, a difference of two window losses equals the difference of the whole-frame losses.
    inputs: per frame, Gaussians to draw ({means, quats, log_scales, opacities, features}: render
    inputs of its modality at t, or the rows of them that reach its window) instead of the model."""
    total = 0.0
    for i, ((modality, camera, target, valid), win) in enumerate(zip(frames, windows or [None] * len(frames))):
        if win == ():
            continue
        valid = valid if modality != "rgb" and valid is not None and valid.any() else None
        norm = target.numel() if valid is None else int(valid.sum())
        if win is not None:
            x0, y0, w, h = win
            camera, target = camera.crop(x0, y0, w, h), target[y0:y0 + h, x0:x0 + w]
            valid = None if valid is None else valid[y0:y0 + h, x0:x0 + w]
        if inputs is None:
            pred = render_frame(model, modality, t, camera)
        else:
            pred = draw(model, modality, inputs[i], camera)[0]
        err = (pred - target).abs() if modality == "rgb" else (pred[..., 0] - target).abs()
        total += float((err[valid] if valid is not None else err).double().sum()) / norm
    return total / max(len(frames), 1)


def footprint(camera, positions: list[tuple[torch.Tensor, torch.Tensor]], log_scales: torch.Tensor) -> tuple:
    """The pixel window (x0, y0, w, h) of camera holding every pixel that Gaussians with log_scales
    (M, 3) can draw at any of positions [(means (M, 3), quats (M, 4))]: pixel_boxes at full opacity
    (their widest). () when they draw nothing in the view."""
    ones = torch.ones(log_scales.shape[0])
    lo, hi = [], []
    for means, quats in positions:
        box_lo, box_hi, drawn = pixel_boxes(camera, means, quats, log_scales, ones)
        lo.append(box_lo[drawn])
        hi.append(box_hi[drawn])
    lo, hi = torch.cat(lo), torch.cat(hi)
    if lo.numel() == 0:
        return ()
    x0, y0 = (max(int(v), 0) for v in lo.amin(0).floor())
    x1, y1 = (int(v) for v in hi.amax(0).ceil())
    x1, y1 = min(x1, camera.width), min(y1, camera.height)
    return (x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else ()


PER_GAUSSIAN = ("means", "quats", "log_scales", "opacities", "features")


def reaching(camera, g: dict[str, torch.Tensor], window: tuple) -> torch.Tensor:
    """(R,) sorted indices of the Gaussians g (render inputs) whose pixel_boxes in camera (at their
    opacities) reach window (x0, y0, w, h): all a render of it needs."""
    x0, y0, w, h = window
    lo, hi, drawn = pixel_boxes(camera, g["means"], g["quats"], g["log_scales"], g["opacities"])
    hit = drawn & (hi[:, 0] >= x0) & (lo[:, 0] <= x0 + w) & (hi[:, 1] >= y0) & (lo[:, 1] <= y0 + h)
    return hit.nonzero()[:, 0]


class BodySearch:
    """Renders of the model at time t with one body moved, for place_bases.

    Only body b's Gaussians change between candidates: a body moves its Gaussians after every
    residual (networks, trajectories), and no residual depends on where a body is. So each
    candidate is drawn from render inputs computed once (networks, routing masks, every other
    Gaussian) with b's rows moved from their place before the bodies' motion, scored on the window
    of each frame where b draws (footprint), and drawn from the Gaussians that reach that window
    only: the same pixels as a full render."""

    def __init__(self, model, frames, t: float):
        self.model, self.frames, self.t = model, frames, t
        masks = inference_masks(model)
        with torch.no_grad():
            self.inputs = {m: model.render_inputs(m, t, mask=None if masks is None else masks[m])
                           for m in {f[0] for f in frames}}
        self._rows: dict[int, torch.Tensor] = {}

    def rows(self, b: int) -> torch.Tensor:
        """(M,) indices of body b's Gaussians (the bodies do not change during a search)."""
        if b not in self._rows:
            self._rows[b] = (self.model.gaussians["motion_basis"].long() == b + 1).nonzero()[:, 0]
        return self._rows[b]

    def before_motion(self, modality: str, idx: torch.Tensor, key: str) -> torch.Tensor:
        """Rows idx of a geometry tensor (means, quats or log_scales) of modality's render inputs
        before the bodies move them: canonical + the residuals that render applied."""
        residual = self.inputs[modality]["geometry_residuals"].get(key)
        value = self.model.gaussians[key][idx]
        return value if residual is None else value + residual[idx]

    @contextmanager
    def offset(self, b: int, knots: torch.Tensor, offset: torch.Tensor):
        """Within: body b's translation knots `knots` moved by offset (3,); restored exactly after."""
        translation = self.model.motion.translation.data
        saved = translation[b, knots].clone()
        translation[b, knots] = saved + offset
        try:
            yield
        finally:
            translation[b, knots] = saved

    def moved(self, modality: str, b: int, knots: torch.Tensor,
              offset: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Body b's Gaussians (means, quats) in modality's render at t with offset (3,) added to its
        translation knots."""
        model, g, idx = self.model, self.model.gaussians, self.rows(b)
        with self.offset(b, knots, offset):
            return apply_motion(self.before_motion(modality, idx, "means"), self.before_motion(modality, idx, "quats"),
                                g["motion_basis"][idx], model.dynamic_gate(idx), model.motion, self.t)

    def plan(self, b: int, knots: torch.Tensor, offsets: list[torch.Tensor]) -> list:
        """Per frame, (window where body b draws as it is or with any of offsets, the rows of the
        render inputs that reach it, body b's places among those rows)."""
        idx = self.rows(b)
        positions = {m: [self.moved(m, b, knots, o) for o in [torch.zeros(3)] + offsets] for m in self.inputs}
        plans = []
        for modality, camera, _, _ in self.frames:
            window = footprint(camera, positions[modality], self.before_motion(modality, idx, "log_scales"))
            if window == ():
                plans.append(((), None, None))
                continue
            inp = self.inputs[modality]
            sub = torch.unique(torch.cat([reaching(camera, inp, window), idx]))
            plans.append((window, {k: inp[k][sub] for k in PER_GAUSSIAN}, torch.searchsorted(sub, idx)))
        return plans

    def loss(self, b: int, knots: torch.Tensor, offset: torch.Tensor, plans: list) -> float:
        """window_loss with body b's translation knots moved by offset (3,)."""
        means = {m: self.moved(m, b, knots, offset)[0] for m in self.inputs}
        inputs = [None if g is None else {**g, "means": g["means"].index_copy(0, pos, means[m])}
                  for (_, g, pos), (m, *_) in zip(plans, self.frames)]
        return window_loss(self.model, self.frames, self.t, [w for w, _, _ in plans], inputs)

    def move(self, b: int, knots: torch.Tensor, offset: torch.Tensor) -> None:
        """Keep offset: body b's knots move, and so do its rows of the cached inputs."""
        self.model.motion.translation.data[b, knots] += offset
        idx = self.rows(b)
        for modality, inp in self.inputs.items():
            inp["means"] = inp["means"].index_copy(0, idx, self.moved(modality, b, knots, torch.zeros(3))[0])


def hold_at_depth(search: BodySearch, b: int, knots: torch.Tensor, camera, centre: torch.Tensor, depth: float,
                  prev_means: torch.Tensor, gate: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, float]:
    """Slide body b (its knots `knots`) along camera's ray through its centre (3,) at camera depth
    `depth` to the depth its Gaussians had at the previous step (prev_means (M, 3), weights (M,)):
    its pixel stays, the depth velocity of the constant-velocity guess is dropped. A Gaussian
    follows its knots by its gate, so the knots move by the shift over the weighted mean gate.
    -> (centre, depth) after the move (unchanged if it cannot move)."""
    rot, tr = camera.viewmat[:3, :3], camera.viewmat[:3, 3]
    z_prev = float(rot[2] @ ((prev_means * weight[:, None]).sum(0) / weight.sum()) + tr[2])
    mean_gate = float((gate * weight).sum() / weight.sum())
    if z_prev <= 1e-3 or mean_gate < 0.05:
        return centre, depth
    shift = (z_prev / depth - 1.0) * (centre - camera.center)      # along the ray
    search.move(b, knots, shift / mean_gate)
    return centre + shift, z_prev


MIN_RAY_DROP = 0.1     # sin(~6 deg): a ray flatter than this meets a height too far off to trust


def at_height(point: torch.Tensor, eye: torch.Tensor, up: torch.Tensor, height: float) -> torch.Tensor | None:
    """Where the ray from eye (3,) through point (3,) is at `height` along up (3,); None where the
    ray is within ~6 degrees of level or meets that height more than 1.5x nearer or farther than
    point (a guess that far off is lost, not merely at the wrong depth)."""
    ray = point - eye
    drop = float(ray @ up)
    if abs(drop) < MIN_RAY_DROP * float(ray.norm()):
        return None
    s = (height - float(eye @ up)) / drop
    return eye + s * ray if 1 / 1.5 <= s <= 1.5 else None


def level_offsets(offsets: list[torch.Tensor], centre: torch.Tensor, eye: torch.Tensor,
                  up: torch.Tensor) -> list[torch.Tensor]:
    """Image-plane offsets (3,) of a body at centre (3,) seen from eye, each moved along its own ray
    to the centre's height: the same pixels, no change of height (horizontal part where the ray
    is too flat)."""
    height = float(centre @ up)
    out = []
    for o in offsets:
        p = at_height(centre + o, eye, up, height)
        out.append(p - centre if p is not None else o - (o @ up) * up)
    return out


def hold_at_height(search: BodySearch, b: int, knots: torch.Tensor, camera, centre: torch.Tensor,
                   prev_means: torch.Tensor, gate: torch.Tensor, weight: torch.Tensor,
                   up: torch.Tensor) -> tuple[torch.Tensor, float]:
    """Slide body b (its knots `knots`) along camera's ray through its centre (3,) to the height
    along up its Gaussians had at the previous step (prev_means (M, 3), weights (M,)): its pixel
    stays, and its depth follows from its height. -> (centre, camera depth) after the move."""
    rot, tr = camera.viewmat[:3, :3], camera.viewmat[:3, 3]
    height = float(up @ ((prev_means * weight[:, None]).sum(0) / weight.sum()))
    mean_gate = float((gate * weight).sum() / weight.sum())
    target = at_height(centre, camera.center, up, height)
    if target is not None and mean_gate >= 0.05:
        search.move(b, knots, (target - centre) / mean_gate)
        centre = target
    return centre, float(rot[2] @ centre + tr[2])


@torch.no_grad()
def place_bases(model, frames, t: float, side: str, min_opacity_mass: float = 1.0,
                pixel_steps: tuple[float, ...] = (6.0, 3.0), hold_depth: bool = False,
                up: torch.Tensor | None = None) -> None:
    """Where each motion basis is at a time step the window just took in: a coarse search before
    the gradient refines it. The knots of the new step (and beyond, on `side` 'lo' or 'hi') start
    at constant velocity; for each basis with Gaussians near the view, offsets of (pixel_steps)
    pixels across the first frame's image plane (a 3x3 grid per step size, best kept) are tried,
    and the one with the lowest loss over `frames` (the views at t) is kept. Depth is left to the
    trajectory smoothness (MotionBases.smoothness): one view pins it poorly. Photometric gradients
    only pull an object that already overlaps its image; a search finds one that the
    constant-velocity guess missed by a few pixels. hold_depth: before the search each body slides
    along the first frame's ray to the depth it had at the previous step (hold_at_depth). up (3,):
    instead, each body slides to the height it had at the previous step and the search keeps that
    height (hold_at_height, level_offsets)."""
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
    search = BodySearch(model, frames, t)
    for b in range(motion.count):
        sel = basis == b + 1
        if float(weight[sel].sum()) < min_opacity_mass:
            continue
        means, _ = apply_motion(g["means"][sel], None, g["motion_basis"][sel], gate[sel], motion, t)
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
            if hold_depth or up is not None:
                prev, _ = apply_motion(g["means"][sel], None, g["motion_basis"][sel], gate[sel], motion,
                                       k_prev / (knots - 1))
                if up is not None:
                    centre, depth = hold_at_height(search, b, rows, cam, centre, prev, gate[sel], w, up)
                else:
                    centre, depth = hold_at_depth(search, b, rows, cam, centre, depth, prev, gate[sel], w)
        steps = [max(s, 0.5 ** i * 0.5 * speed) for i, s in enumerate(pixel_steps)]
        for s in steps:
            group = [(i * s * depth / cam.fx) * rot[0] + (j * s * depth / cam.fy) * rot[1]
                     for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
            if up is not None:
                group = level_offsets(group, centre, cam.center, up)
            plans = search.plan(b, rows, group)
            best, best_loss = None, search.loss(b, rows, torch.zeros(3), plans)
            for offset in group:
                loss = search.loss(b, rows, offset, plans)
                if loss < best_loss - 1e-6:
                    best, best_loss = offset, loss
            if best is not None:
                search.move(b, rows, best)
                centre = centre + best
