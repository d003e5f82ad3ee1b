"""Moving objects' 3D paths from the thermal training frames alone: blobs, tracks, triangulation.

One view per instant cannot measure how far a moving object is along its ray, and the training
views' loss does not tell either (docs/training.md, "Where a path's depth goes wrong"). The whole
sequence can: the handheld rig sweeps tens of degrees while the object moves, so the rays to one
object at different instants meet only where a smooth path lets them ("trajectory
triangulation"). Here

1. each thermal training frame gives its blobs: connected regions at least 10, 20 or 40 K hotter
   or colder than the frame's median (a hot or cold object is the sharpest thing a thermal camera
   sees; two objects whose blobs touch at one level may part at a hotter one);
2. blobs of one level are linked over time into tracks (nearest predicted centroid, similar area);
3. a track's frames where its blob is whole (not on the border, its area near that of its
   neighbours in the track: not cut, not merged; an object nearing the camera grows smoothly) give
   one ray per instant, and those where one side of the image cuts it the coordinate along that side
   (`border_frames`), and a path with `knots` knots, linear between
   them, smooth (second differences) and level (its height along up nearly constant: things move
   on a table or a floor), is fitted to them: linear least squares, then Levenberg-Marquardt on
   the pixel errors; with `rest_px` > 0 (off by default: it failed its held-out rule on the fast
   case's median), spans of frames that one still point explains hold the path still
   (`rest_windows`; docs/training.md, "A path that stops stays put");
4. a track moves where no still point explains it (3 px) and its path travels; frames where its
   blob swallows a still track's blob are dropped and it is fitted again; of the tracks of one
   object (at several levels), the one with the most frames is kept.
   With `still_share` > 0 (off by default: it failed its held-out rule on outside RGB), still
   things are found before linking instead (`still_groups`), so a track cannot carry a hot cup that
   a moving object passes (docs/training.md, "Still hot things found before linking").

On the simulator's development seeds 40-43 (`bench/results/tracked-paths/probe_paths.txt`, with
the blob size judged against the whole track's) this found 10 of the 13 moving objects, each path
0.7-9 cm from the object's centre (median over time), and no path where nothing moves; on seeds
40-49 25 of 33 with the rule of 2026-12-04 (`bench/results/whole-window/probe-dev-after.txt`), 26
with `border_frames` (`bench/results/border-frames/probe-dev-after.txt`). Most it misses
overlap a hot cup in the image for most of the sequence. With the simulator's masks as blobs the
same fit is 1-7 cm off. The bodies' paths that the training loss tracks were 0.2-1 m off along the
training rays.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from scipy.optimize import least_squares

from recon.config import PathConfig
from recon.dtg.points import project


@dataclass
class Blob:
    time: float
    centroid: np.ndarray          # (2,) pixel (x, y), pixel centres at +0.5
    area: int
    sign: int                     # +1 hotter than the frame's median, -1 colder
    border: bool                  # touches the image border (may be cut)
    pixels: np.ndarray            # (area,) its pixels' flat indices (y * width + x), sorted
    width: int
    kelvin: float = float("nan")  # its pixels' median temperature (nan: not known)
    cut: tuple = (False, False)   # touches a left/right (x) or top/bottom (y) border: that
                                  # coordinate of its centroid is pulled inwards

    @property
    def diameter(self) -> float:
        return 2 * float(np.sqrt(self.area / np.pi))

    def covers(self, xy: np.ndarray) -> bool:
        """Whether pixel position xy (2,) lies on the blob."""
        i = int(xy[1]) * self.width + int(xy[0])
        k = int(np.searchsorted(self.pixels, i))
        return k < len(self.pixels) and int(self.pixels[k]) == i


@dataclass
class TrackedPath:
    """One object's path: positions at the knots (K, 3) world, linear between them over t in [0, 1]."""
    knots: torch.Tensor
    reference: float              # the instant its blob is largest and whole: where a body is built
    radius: float                 # metres, from the blob's area and depth at `reference`
    reprojection: float           # median px at 160 px wide
    still_error: float            # median px at 160 px wide of the best still point: large where it moves
    frames: int                   # whole frames fitted
    seen: dict                    # time -> Blob: the fitted frames' blobs
    covariance: np.ndarray | None = None   # (3K, 3K) the knots' covariance (m^2) by the fit itself
    rests: tuple = ()             # (t0, t1) spans where the fit holds it still (PathConfig.rest_px)

    def at(self, t: torch.Tensor | float) -> torch.Tensor:
        """(T, 3) positions at times t (T,)."""
        t = torch.as_tensor(t, dtype=torch.float32).reshape(-1)
        return torch.as_tensor(hat_basis(t.numpy(), len(self.knots)), dtype=torch.float32) @ self.knots

    def covariance_at(self, t: torch.Tensor | np.ndarray) -> np.ndarray | None:
        """(T, 3, 3) covariance (m^2) of the positions at times t (T,), from the knots' (None: unknown)."""
        if self.covariance is None:
            return None
        basis = hat_basis(np.asarray(t, dtype=np.float64).reshape(-1), len(self.knots))        # (T, K)
        c = self.covariance.reshape(len(self.knots), 3, len(self.knots), 3)
        return np.einsum("tk,kalb,tl->tab", basis, c, basis)


def hat_basis(t: np.ndarray, knots: int) -> np.ndarray:
    """(T, K) weights of linear interpolation between K uniform knots over [0, 1] at times t (T,)."""
    x = np.clip(np.asarray(t, dtype=np.float64), 0, 1) * (knots - 1)
    i = np.minimum(np.floor(x).astype(int), knots - 2)
    a = x - i
    basis = np.zeros((len(x), knots))
    basis[np.arange(len(x)), i] = 1 - a
    basis[np.arange(len(x)), i + 1] = a
    return basis


def projection(camera) -> np.ndarray:
    """(3, 4) K [R | t] of a camera (world -> pixels, OpenCV axes)."""
    k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    return k @ camera.viewmat[:3].double().numpy()


def to_pixels(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, 2) pixels of points (T, 3) or one point (3,) through projections (T, 3, 4); a point on a
    camera's plane (depth ~0) lands far off, not at infinity."""
    if points.ndim == 2:
        p = np.einsum("tij,tj->ti", projections[:, :, :3], points) + projections[:, :, 3]
    else:
        p = projections[:, :, :3] @ points + projections[:, :, 3]
    z = np.where(np.abs(p[:, 2]) < 1e-6, 1e-6, p[:, 2])
    return p[:, :2] / z[:, None]


def dlt_rows(projections: np.ndarray, pixels: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(2T, 4) rows r with r . (X, 1) = 0 where the point X projects to pixels (T, 2) through
    projections (T, 3, 4): the linear (DLT) triangulation equations, x rows then y rows, each
    scaled by its coordinate's weight in weights (T, 2) (None: all 1)."""
    rows = np.concatenate([projections[:, 0] - pixels[:, :1] * projections[:, 2],
                           projections[:, 1] - pixels[:, 1:] * projections[:, 2]])
    return rows if weights is None else rows * np.concatenate([weights[:, 0], weights[:, 1]])[:, None]


def path_priors(knots: int, smoothness: float, level: float, up: np.ndarray | None,
                rests: list[tuple[float, float]] = (), rest_weight: float = 0.0) -> np.ndarray:
    """(R, 3K) rows whose product with a path's flattened knots (3K,) are its prior residuals:
    sqrt(smoothness) x the knots' second differences, sqrt(level) x their heights' spread along
    up (3,) (None or zero: no such rows), and sqrt(rest_weight) x the steps between consecutive
    knots that both lie in one rest window (t0, t1) of `rests` (the object stands still there)."""
    second = np.zeros((max(knots - 2, 0), knots))
    for k in range(knots - 2):
        second[k, k:k + 3] = (1, -2, 1)
    priors = [np.kron(second, np.eye(3)) * np.sqrt(smoothness)]
    if up is not None and level > 0 and np.linalg.norm(up) > 0:
        spread = np.eye(knots) - 1.0 / knots
        priors.append(np.kron(spread, np.asarray(up, dtype=np.float64)[None]) * np.sqrt(level))
    at = np.linspace(0, 1, knots)
    steps = [k for k in range(knots - 1) for t0, t1 in rests if t0 - 1e-9 <= at[k] and at[k + 1] <= t1 + 1e-9]
    if steps and rest_weight > 0:
        first = np.zeros((len(steps), knots))
        for row, k in enumerate(steps):
            first[row, k:k + 2] = (-1, 1)
        priors.append(np.kron(first, np.eye(3)) * np.sqrt(rest_weight))
    return np.concatenate(priors)


def rest_windows(times: np.ndarray, projections: np.ndarray, pixels: np.ndarray, weights: np.ndarray,
                 tolerance_px: float, min_frames: int) -> list[tuple[float, float]]:
    """(t0, t1) spans of consecutive fitted frames (times (T,) in order) that one still point
    explains, each frame's pixel error (over the coordinates weights (T, 2) keep) at most
    tolerance_px, at least min_frames of them: where the object may stand still. Longest first,
    not overlapping.

    Why: a path's smoothness (second differences) charges nothing for a constant velocity, so
    where the object rests, a path sliding along the rays at a steady pace fits as well as the
    still one, and a stop (the family's fast objects cover their path, then stop) costs a kink the
    fit avoids: at rest the paths of development fast seeds 45 and 46 stayed 11-16 cm off, where
    the same frames triangulated as one still point were 0.1-2.4 cm off
    (bench/results/rest-windows/). A moving object's rays can meet near one point too
    (development inside 40's ball travelled 0.32 m over 11 frames that a still point explains
    within 1 px; neither the rays' spread nor the blobs' sizes told them apart), so fit_track
    keeps a window only where standing still costs the whole track no pixels (rest_cost)."""
    n = len(times)
    if tolerance_px <= 0 or n < min_frames:
        return []

    def fits(i: int, j: int) -> bool:        # frames i..j (inclusive) explained by one still point
        p, px, w = projections[i:j + 1], pixels[i:j + 1], weights[i:j + 1]
        x = np.linalg.svd(dlt_rows(p, px, w))[2][-1]
        if abs(x[3]) < 1e-12:                # a point at infinity: no still object
            return False
        point = x[:3] / x[3]
        depth = p[:, 2, :3] @ point + p[:, 2, 3]
        err = np.linalg.norm((to_pixels(p, point) - px) * w, axis=1)
        return bool(np.all(depth > 0) and err.max() <= tolerance_px)

    spans = []
    for i in range(n - min_frames + 1):
        j = i + min_frames - 1
        if not fits(i, j):
            continue
        while j + 1 < n and fits(i, j + 1):
            j += 1
        spans.append((i, j))
    out, used = [], np.zeros(n, dtype=bool)
    for i, j in sorted(spans, key=lambda s: s[0] - s[1]):
        if not used[i:j + 1].any():
            used[i:j + 1] = True
            out.append((float(times[i]), float(times[j])))
    return out


def triangulate_path(times: np.ndarray, projections: np.ndarray, pixels: np.ndarray, knots: int,
                     smoothness: float, level: float, up: np.ndarray | None, robust_px: float = 0.0,
                     weights: np.ndarray | None = None, rests: list[tuple[float, float]] = (),
                     rest_weight: float = 0.0) -> np.ndarray:
    """(K, 3) knots of the smooth path whose point at each time times (T,) projects to pixels (T, 2)
    by projections (T, 3, 4): least squares over the pixel errors, smoothness x the knots' second
    differences (metres) and level x their heights' spread along up (3,) (None or zero: no such
    prior). Started from the linear (algebraic) solution, refined by Levenberg-Marquardt.

    Depth is measurable because the rig's path differs from the object's: a handheld sweep shakes
    and changes pace. A camera gliding on a path as smooth and level as the object's leaves a family
    of paths, scaled about the camera, that fit equally well.

    robust_px > 0: pixel errors beyond it count as soft-L1, so a few frames whose blob merged with
    another pull the path less (such frames still move it: a path scaled about the camera explains
    them, tests/test_paths.py).

    weights (T, 2), 0 or 1 (None: all 1): which pixel coordinates count (a blob cut by the image's
    left or right border has its centroid's x pulled inwards; its y still holds).

    rests: (t0, t1) windows where the object stands still (rest_windows): consecutive knots inside
    one cost rest_weight x their step squared (metres)."""
    w = np.ones_like(pixels) if weights is None else np.asarray(weights, dtype=np.float64)
    basis = hat_basis(times, knots)                                          # (T, K)
    prior = path_priors(knots, smoothness, level, up, rests, rest_weight)    # (R, 3K)
    rows = dlt_rows(projections, pixels, w)                                  # (2T, 4)
    a = (np.concatenate([basis, basis])[:, :, None] * rows[:, None, :3]).reshape(len(rows), 3 * knots)
    start = np.linalg.lstsq(np.concatenate([a, prior]), np.concatenate([-rows[:, 3], np.zeros(len(prior))]),
                            rcond=None)[0]
    depth = np.einsum("tj,tj->t", projections[:, 2, :3], basis @ start.reshape(knots, 3)) + projections[:, 2, 3]
    if np.all(depth > 0):      # the algebraic residual is the pixel error times the depth: in pixels
        scale = 1.0 / np.median(depth)
        start = np.linalg.lstsq(np.concatenate([a * scale, prior]),
                                np.concatenate([-rows[:, 3] * scale, np.zeros(len(prior))]), rcond=None)[0]

    def residuals(x: np.ndarray) -> np.ndarray:
        return np.concatenate([((to_pixels(projections, basis @ x.reshape(knots, 3)) - pixels) * w).ravel(), prior @ x])

    if robust_px > 0:   # soft-L1 on every residual: the priors' are well below robust_px, so stay quadratic
        fit = least_squares(residuals, start, method="trf", loss="soft_l1", f_scale=robust_px, max_nfev=200 * len(start))
    else:
        fit = least_squares(residuals, start, method="lm", max_nfev=200 * len(start))
    return fit.x.reshape(knots, 3)


def knot_covariance(knots: np.ndarray, times: np.ndarray, projections: np.ndarray, pixels: np.ndarray,
                    prior: np.ndarray, weights: np.ndarray, floor_px: float) -> np.ndarray:
    """(3K, 3K) covariance (m^2) of a fitted path's knots (K, 3): s^2 (J^T J)^-1 of the fit's
    residuals (pixel errors over the coordinates weights (T, 2) keep, and the priors' rows (R, 3K))
    at the knots, s^2 the pixel errors' mean square, at least floor_px^2. Small where the rig's
    sweep pins the path, large along the rays where it does not (a rig that glides as the object
    does): how far training may move a body from its path before it contradicts the frames."""
    basis = hat_basis(times, len(knots))
    x = knots.ravel()

    def pixel_rows(x: np.ndarray) -> np.ndarray:
        return ((to_pixels(projections, basis @ x.reshape(-1, 3)) - pixels) * weights).ravel()
    r = pixel_rows(x)
    step = 1e-6
    jac = np.stack([(pixel_rows(x + step * e) - r) / step for e in np.eye(len(x))], 1)
    jac = np.concatenate([jac, prior])
    s2 = max(float(np.sum(r ** 2)) / max(float(weights.sum()), 1.0), floor_px ** 2)
    return s2 * np.linalg.pinv(jac.T @ jac)


def reprojection_errors(knots: np.ndarray, times: np.ndarray, projections: np.ndarray,
                        pixels: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(T,) pixel distance between each fitted point's projection and its observed pixel, over the
    coordinates weights (T, 2) keep (None: both)."""
    d = to_pixels(projections, hat_basis(times, len(knots)) @ knots) - pixels
    return np.linalg.norm(d if weights is None else d * weights, axis=1)


def frame_blobs(kelvin: np.ndarray, valid: np.ndarray | None, time: float, contrast: float,
                settings: PathConfig) -> list[Blob]:
    """Blobs of one thermal frame (H, W) in kelvin: connected regions `contrast` kelvin hotter or
    colder than its median."""
    h, w = kelvin.shape
    ok = np.isfinite(kelvin) if valid is None else (valid & np.isfinite(kelvin))
    if not ok.any():
        return []
    median = float(np.median(kelvin[ok]))
    out = []
    for sign in (1, -1):
        mask = (ok & (sign * (kelvin - median) >= contrast)).astype(np.uint8)
        count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        for i in range(1, count):
            x, y, bw, bh, area = stats[i]
            if not settings.min_area * h * w <= area <= settings.max_area * h * w:
                continue
            cut = (bool(x == 0 or x + bw == w), bool(y == 0 or y + bh == h))
            pixels = np.flatnonzero(labels == i)
            out.append(Blob(time, centroids[i] + 0.5, int(area), sign, cut[0] or cut[1], pixels, w,
                            float(np.median(kelvin.ravel()[pixels])), cut))
    return out


def link_tracks(blobs: list[list[Blob]], width: int, max_kelvin: float = 0.0) -> list[list[Blob]]:
    """Tracks through per-instant blob lists (in time order): each blob continues the track of the
    same sign whose predicted centroid (constant velocity) is nearest, within its size plus 5 % of
    the width and with an area within 3x (and, with max_kelvin > 0, a median temperature within
    max_kelvin of the track's last blob: an object's temperature changes slowly, while the cup a
    ball passed is another temperature); else it starts a track. A track may miss instants
    (occlusion) and continue."""
    tracks: list[list[Blob]] = []
    for frame in blobs:
        taken = set()
        for blob in sorted(frame, key=lambda b: -b.area):
            best, best_d = None, np.inf
            for i, track in enumerate(tracks):
                last = track[-1]
                if i in taken or last.sign != blob.sign or not 1 / 3 <= blob.area / last.area <= 3:
                    continue
                if max_kelvin > 0 and abs(blob.kelvin - last.kelvin) > max_kelvin:   # nan: no test
                    continue
                guess = last.centroid
                if len(track) > 1:
                    prev = track[-2]
                    rate = (last.centroid - prev.centroid) / max(last.time - prev.time, 1e-9)
                    guess = last.centroid + rate * (blob.time - last.time)
                d = float(np.linalg.norm(blob.centroid - guess))
                if d < best_d and d <= np.sqrt(blob.area) + 0.05 * width:
                    best, best_d = i, d
            if best is None:
                tracks.append([blob])
                taken.add(len(tracks) - 1)
            else:
                tracks[best].append(blob)
                taken.add(best)
    return tracks


def triangulate_point(projections: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(3,) the point seen at pixels (T, 2) through projections (T, 3, 4), T >= 2: linear (DLT)."""
    x = np.linalg.svd(dlt_rows(projections, pixels))[2][-1]
    return x[:3] / (x[3] if abs(x[3]) > 1e-12 else 1e-12)


def still_groups(blobs: list[list[Blob]], projections: np.ndarray, settings: PathConfig
                 ) -> tuple[list[list[Blob]], list[list[Blob]]]:
    """Blobs of things that stay in place, found before any linking: (groups, the other blobs per
    instant). A group is the blobs (one per instant, same sign) whose centroids lie within
    `min_still_error` px (at 160 px wide) of one 3D point's projection, in at least `still_share` of
    the instants: hypotheses from blob pairs of widely spaced instants (linear triangulation), the
    best supported refined on its support, its blobs taken out, repeated. A still hot thing that a
    moving one passes merges with it for a while: linked over time, the merged blobs carried its
    track away (family-inside 40's cup fitted as a moving body) or its blobs carried a moving
    object's track into it. Taken out first, only the merged blobs remain to link.
    blobs: per instant (T lists); projections: (T, 3, 4)."""
    rest = [list(frame) for frame in blobs]
    n = len(rest)
    if settings.still_share <= 0 or n < 2:
        return [], rest
    width = next((b.width for frame in rest for b in frame), 160)
    tol = settings.min_still_error * width / 160
    need = max(settings.min_frames, int(np.ceil(settings.still_share * n)))
    pairs = [(i, j) for i, j in ((0, n // 2), (n // 4, 3 * n // 4), (n // 2, n - 1), (0, n - 1)) if i != j]
    groups = []
    while True:
        best, best_hits = None, []
        for i, j in pairs:
            for a in rest[i]:
                for b in rest[j]:
                    if a.sign != b.sign or not 0.5 <= a.area / b.area <= 2:
                        continue
                    point = triangulate_point(projections[[i, j]], np.stack([a.centroid, b.centroid]))
                    hits = _still_hits(point, a.sign, rest, projections, tol, settings.still_area)
                    if len(hits) > len(best_hits):
                        best, best_hits = (a.sign, point), hits
        if len(best_hits) < need:
            return groups, rest
        sign, point = best
        pixels = np.stack([blob.centroid for _, blob in best_hits])
        point = least_squares(lambda x: (to_pixels(projections[[k for k, _ in best_hits]], x) - pixels).ravel(),
                              point, method="lm").x
        hits = _still_hits(point, sign, rest, projections, tol, settings.still_area) or best_hits
        for k, blob in hits:
            rest[k] = [b for b in rest[k] if b is not blob]
        groups.append([blob for _, blob in hits])


def _still_hits(point: np.ndarray, sign: int, blobs: list[list[Blob]], projections: np.ndarray,
                tol: float, spread: float) -> list[tuple[int, Blob]]:
    """(instant, blob) where a blob of `sign` has its centroid within tol px of point's projection
    (in front of the camera) and an area within `spread` x the median of those blobs: a still
    thing's blob keeps its size over a sweep, and one merged with a thing passing near its centre
    does not (the merged blob is the passing thing's too)."""
    depth = projections[:, 2, :3] @ point + projections[:, 2, 3]
    seen = to_pixels(projections, point)
    out = []
    for k, frame in enumerate(blobs):
        if depth[k] <= 0:
            continue
        near = [(float(np.linalg.norm(b.centroid - seen[k])), i) for i, b in enumerate(frame) if b.sign == sign]
        if near and min(near)[0] <= tol:
            out.append((k, frame[min(near)[1]]))
    if not out:
        return out
    typical = float(np.median([blob.area for _, blob in out]))
    return [(k, blob) for k, blob in out if 1 / spread <= blob.area / typical <= spread]


def typical_areas(blobs: list[Blob], window: int) -> np.ndarray:
    """(B,) the area each blob of a track (in time order) should have if whole: the median over the
    `window` blobs before and after it and itself (an object approaching the camera grows smoothly;
    a cut or a merge changes the area from one frame to the next), or with window 0 the track's 25th
    percentile (one size for the whole track)."""
    areas = np.array([b.area for b in blobs], dtype=np.float64)
    if window <= 0:
        return np.full(len(areas), np.percentile(areas, 25))
    return np.array([np.median(areas[max(0, i - window):i + window + 1]) for i in range(len(areas))])


def fit_track(track: list[Blob], cameras: dict, up: np.ndarray | None, settings: PathConfig) -> TrackedPath | None:
    """The path of one track (cameras: time -> the thermal camera there), or None when it has too
    few whole (and, with border_frames, cut) frames or no path explains them."""
    whole = [b for b in track if not b.border]
    # with border_frames, a blob cut by one side's border (not a corner) adds the coordinate along it,
    # and counts as half a frame: one coordinate of two (a track of mostly cut frames leaves the depth
    # loose: family-inside 0 at 96x72 got a can path 0.4 m off from 6 whole and 7 cut frames)
    edge = [b for b in track if sum(b.cut) == 1] if settings.border_frames else []

    def enough(whole: list[Blob]) -> bool:
        return (len(whole) >= (settings.min_whole if edge else settings.min_frames)
                and len(whole) + 0.5 * len(edge) >= settings.min_frames)

    if not enough(whole):
        return None
    p25 = np.percentile([b.area for b in whole], 25)
    whole = [b for b, typical in zip(whole, typical_areas(whole, settings.whole_window))
             if settings.whole[0] <= b.area / typical <= settings.whole[1]
             and settings.whole_track[0] <= b.area / p25 <= settings.whole_track[1]]
    if not enough(whole):
        return None
    used = sorted(whole + edge, key=lambda b: b.time)
    times = np.array([b.time for b in used])
    projections = np.stack([projection(cameras[b.time]) for b in used])
    pixels = np.stack([b.centroid for b in used])
    weights = np.array([[float(not b.cut[0]), float(not b.cut[1])] for b in used])   # whole: (1, 1)
    width = cameras[used[0].time].width

    def fit(rests: list) -> np.ndarray:
        return triangulate_path(times, projections, pixels, settings.knots, settings.smoothness, settings.level, up,
                                settings.robust_px * width / 160, weights, rests, settings.rest_weight)

    def rms(knots: np.ndarray) -> float:
        return float(np.sqrt(np.mean(reprojection_errors(knots, times, projections, pixels, weights) ** 2)))

    knots, rests = fit([]), []
    cost = rms(knots)
    for window in rest_windows(times, projections, pixels, weights, settings.rest_px * width / 160, settings.rest_frames):
        trial = fit(rests + [window])       # kept where standing still costs the whole track no pixels
        if (trial_cost := rms(trial)) <= cost + settings.rest_cost * width / 160:
            knots, rests, cost = trial, rests + [window], trial_cost
    error = float(np.median(reprojection_errors(knots, times, projections, pixels, weights))) * 160 / width
    r = max((i for i, b in enumerate(used) if not b.border), key=lambda i: (used[i].area, -abs(used[i].time - 0.5)))
    ref, cam = used[r], cameras[used[r].time]
    point = hat_basis(np.array([ref.time]), settings.knots)[0] @ knots
    depth = float(projections[r, 2, :3] @ point + projections[r, 2, 3])
    if depth <= 0 or error > settings.max_reprojection:
        return None
    radius = np.sqrt(ref.area / np.pi) * depth / cam.fx
    covariance = knot_covariance(knots, times, projections, pixels,
                                 path_priors(settings.knots, settings.smoothness, settings.level, up, rests,
                                             settings.rest_weight), weights,
                                 settings.floor_px * width / 160)
    return TrackedPath(torch.as_tensor(knots, dtype=torch.float32), ref.time, float(radius), error,
                       still_point_error(projections, pixels, knots.mean(0), weights) * 160 / width, len(used),
                       {b.time: b for b in used}, covariance, tuple(rests))


def still_point_error(projections: np.ndarray, pixels: np.ndarray, start: np.ndarray,
                      weights: np.ndarray | None = None) -> float:
    """Median pixel error of the one still point that best explains pixels (T, 2) seen through
    projections (T, 3, 4), refined from start (3,), over the coordinates weights (T, 2) keep."""
    w = np.ones_like(pixels) if weights is None else weights

    def residuals(x: np.ndarray) -> np.ndarray:
        return ((to_pixels(projections, x) - pixels) * w).ravel()
    x = least_squares(residuals, start, method="lm").x
    return float(np.median(np.linalg.norm(residuals(x).reshape(-1, 2), axis=1)))


def travel(path: TrackedPath, samples: int = 41) -> float:
    """The path's largest distance from its mean position (metres)."""
    p = path.at(torch.linspace(0, 1, samples))
    return float((p - p.mean(0)).norm(dim=1).max())


@dataclass
class Tracks:
    moving: list[TrackedPath]     # one path per moving object
    still: list[TrackedPath]      # hot or cold things in one place (every contrast level's fit)


def tracked_paths(scene, settings: PathConfig | None = None) -> Tracks:
    """The paths of the hot or cold objects the thermal training frames show, moving and still
    (settings: TrainConfig.paths; None: the defaults)."""
    settings = settings or PathConfig()
    views = [(t, scene.views_at("thermal", t)[0]) for t in scene.times if scene.views_at("thermal", t)]
    if len(views) < settings.min_frames:
        return Tracks([], [])
    frames = []
    for t, view in views:
        target, valid = scene.target(view)
        frames.append((t, scene.kelvin(target).numpy(), None if valid is None else valid.numpy()))
    cameras = {t: view.camera for t, view in views}
    up = scene.up().double().numpy()
    projections = np.stack([projection(view.camera) for _, view in views])
    paths = []
    for level in settings.contrast:
        blobs = [frame_blobs(kelvin, valid, t, level, settings) for t, kelvin, valid in frames]
        groups, blobs = still_groups(blobs, projections, settings)
        paths += [fit_track(track, cameras, up, settings) for track in groups + link_tracks(blobs, views[0][1].camera.width, settings.link_kelvin)]
    floor = settings.min_travel * scene.extent()
    moves = lambda p: travel(p) > floor and p.still_error > settings.min_still_error        # noqa: E731
    fitted = [p for p in paths if p is not None]
    still = [p for p in fitted if not moves(p)]
    moving = []
    for path in (p for p in fitted if moves(p)):
        merged = merged_times(path, still, cameras if settings.still_share > 0 else None)
        if merged:                  # refitted to its frames apart from the still objects
            path = fit_track([b for t, b in path.seen.items() if t not in merged], cameras, up, settings)
        if path is not None and moves(path):
            moving.append(path)
    return Tracks(distinct(moving), still)


def on_still_blobs(scene, still: list[TrackedPath], points: torch.Tensor, share: float = 0.5) -> torch.Tensor:
    """(P,) bool: which points (P, 3) project onto a still path's blob in at least `share` of that
    path's fitted frames where they lie in front of the thermal camera and inside its image: the
    surface of a thing that heats or cools in place (a hot plate, a cooling cup) and what lies
    right behind it."""
    out = torch.zeros(len(points), dtype=torch.bool)
    for path in still:
        hits = torch.zeros(len(points))
        shown = torch.zeros(len(points))
        for t, blob in path.seen.items():
            camera = scene.views_at("thermal", t)[0].camera
            u, v, _, inside = project(camera, points)
            on = torch.zeros(camera.width * camera.height, dtype=torch.bool)
            on[torch.from_numpy(blob.pixels)] = True
            shown += inside
            hits += inside & on[torch.where(inside, v * camera.width + u, 0)]
        out |= (shown > 0) & (hits >= share * shown)
    return out


def merged_times(path: TrackedPath, still: list[TrackedPath], cameras: dict | None = None) -> set[float]:
    """The instants where path's blob is a moving object merged with a still one: a still path's blob
    centre (at any contrast level) lies on it away from its centre (a quarter of its diameter). With
    cameras (time -> camera; `still_share` on), also where a still path's point projects there at
    instants it has no blob (merged: it is this one). Such a blob's centre is neither object's, and
    a smooth path through it fits as well as a real one."""
    out = set()
    for t, blob in path.seen.items():
        for q in still:
            if t in q.seen:
                xy = q.seen[t].centroid
            elif cameras is not None:
                xy = to_pixels(projection(cameras[t])[None], q.at(t).double().numpy())[0]
            else:
                continue
            if (0 <= xy[0] < blob.width and 0 <= xy[1] and blob.covers(xy)
                    and np.linalg.norm(xy - blob.centroid) > 0.25 * blob.diameter):
                out.add(t)
    return out


def same_object(p: TrackedPath, q: TrackedPath) -> bool:
    """Whether two paths were fitted to one object's blobs (at two contrast levels): at the instants
    both saw, their blobs' centres lie within half the larger diameter at least half the time. (In
    3D two fits of one object may differ along the rays, the one direction a view cannot measure.)"""
    both = set(p.seen) & set(q.seen)
    near = [np.linalg.norm(p.seen[t].centroid - q.seen[t].centroid)
            <= 0.5 * max(p.seen[t].diameter, q.seen[t].diameter) for t in both]
    return len(near) > 0 and sum(near) >= 0.5 * len(near)


def distinct(paths: list[TrackedPath]) -> list[TrackedPath]:
    """One path per object: of the paths fitted to one object's blobs, the one fitted to the most
    frames."""
    kept: list[TrackedPath] = []
    for p in sorted(paths, key=lambda p: -p.frames):
        if not any(same_object(p, q) for q in kept):
            kept.append(p)
    return kept
