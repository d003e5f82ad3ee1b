"""Metric scale of an SfM reconstruction (metres per SfM unit).

SfM recovers the RGB camera path up to scale, but the RGB -> thermal extrinsic is in metres: a
thermal pose is the RGB pose composed with it, so its translation (the baseline, 4 cm on the
simulated rig) must be expressed in SfM units. A 10 % scale error moves every thermal camera by
4 mm, about 5 thermal pixels at 320 px wide and 0.6 m. Sources, in the order `recon prepare`
tries them:

1. `--scale` (metres per SfM unit), e.g. from a measured distance;
2. the checkerboard of `rig calibrate` seen in the RGB frames (held up or laid down in view for
   a few seconds): its corners are triangulated with the recovered poses and the median
   adjacent-corner spacing is compared with the known square size;
3. simulated sessions only: the simulator's true camera path (a documented fallback, flagged
   in the report, like the simulator's calibration).

Otherwise the scale is unknown and `recon prepare` refuses, saying what to recapture.
(Thermal multi-view consistency was tried and dropped: a scale error shifts every thermal view
along the baseline, which is fixed in the camera frame, so views taken close in time sample
nearly the same wrong surface point; on a simulated session the cost curve was flat to
+-15 %, see docs/prepare.md.)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from recon.prepare.poses import umeyama
from recon.prepare.simtruth import session_truth
from rig.calibrate import Target, detect_corners

DEPTH_RANGE_M = (0.05, 50.0)   # plausible median camera-to-scene distance of a handheld rig


@dataclass
class ScaleEstimate:
    metres_per_unit: float | None
    method: str                        # "explicit", "target", "simulator" or "none"
    detail: dict = field(default_factory=dict)


def triangulate(rays_o: np.ndarray, rays_d: np.ndarray) -> np.ndarray:
    """Least-squares point closest to rays (K, 3) origins and unit directions -> (3,)."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for o, d in zip(rays_o, rays_d):
        m = np.eye(3) - np.outer(d, d)
        a += m
        b += m @ o
    return np.linalg.solve(a, b)


def scale_from_target(corners: dict[str, np.ndarray], c2w: dict[str, np.ndarray],
                      k_cv: dict[str, np.ndarray], dist: dict[str, np.ndarray],
                      pattern: tuple[int, int], square_m: float, min_views: int = 3,
                      max_spread: float = 0.05) -> ScaleEstimate | None:
    """Triangulate the board's inner corners (N, 2) (OpenCV pixels) seen in registered frames
    and compare the median adjacent-corner spacing with `square_m`. None if seen in fewer than
    `min_views` frames; method "none" if the spacings disagree by more than `max_spread`."""
    names = [n for n in corners if n in c2w]
    if len(names) < min_views:
        return None
    rays = []
    for n in names:
        norm = cv2.undistortPoints(corners[n].reshape(-1, 1, 2).astype(np.float64), k_cv[n], dist[n])[:, 0]
        d = np.concatenate([norm, np.ones((len(norm), 1))], 1) @ c2w[n][:3, :3].T
        rays.append((np.broadcast_to(c2w[n][:3, 3], d.shape), d / np.linalg.norm(d, axis=1, keepdims=True)))
    pts = np.stack([triangulate(np.stack([r[0][i] for r in rays]), np.stack([r[1][i] for r in rays]))
                    for i in range(pattern[0] * pattern[1])]).reshape(pattern[1], pattern[0], 3)
    spacing = np.concatenate([np.linalg.norm(np.diff(pts, axis=1), axis=2).ravel(),
                              np.linalg.norm(np.diff(pts, axis=0), axis=2).ravel()])
    med = float(np.median(spacing))
    spread = float(np.std(spacing) / med) if med > 0 else float("inf")
    detail = {"views": len(names), "spacing_units": round(med, 6), "spacing_spread": round(spread, 4)}
    if spread > max_spread:
        detail["reason"] = f"board corners triangulate inconsistently (spacing spread {spread:.1%})"
        return ScaleEstimate(None, "none", detail)
    return ScaleEstimate(square_m / med, "target", detail)


def scale_from_truth(c2w_units: np.ndarray, c2w_true: np.ndarray) -> ScaleEstimate:
    """Simulated sessions: the similarity between recovered (K, 4, 4) and true (K, 4, 4) camera
    centres gives metres per unit."""
    s, _, _ = umeyama(c2w_units[:, :3, 3], c2w_true[:, :3, 3])
    return ScaleEstimate(s, "simulator", {"views": len(c2w_units)})


def median_depth_units(result) -> float:
    """Median over registered frames of the median depth of the points each observes (SfM units)."""
    seen: dict[str, list[int]] = {n: [] for n in result.c2w}
    for i, track in enumerate(result.tracks):
        for n in set(track):
            seen[n].append(i)
    depths = []
    for n, idx in seen.items():
        if idx:
            w2c = np.linalg.inv(result.c2w[n])
            depths.append(np.median((result.points_xyz[idx] @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]))
    return float(np.median(depths))


def metric_scale(explicit: float | None, session, recovered, selected, target: Target) -> ScaleEstimate:
    """--scale, else the checkerboard in view of >= 3 registered frames, else (simulated sessions)
    the simulator's true camera path, else unknown (method "none" with the reason)."""
    if explicit is not None:
        return ScaleEstimate(explicit, "explicit")
    result = recovered.result
    corners = {}
    for k in recovered.registered:
        c = detect_corners(cv2.cvtColor(selected[k].image, cv2.COLOR_RGB2GRAY), target.pattern, fast=True)
        if c is not None:
            corners[recovered.names[k]] = c
    cams = {n: result.cameras[n] for n in corners}
    est = scale_from_target(corners, result.c2w, {n: c.opencv_matrix() for n, c in cams.items()},
                            {n: c.coefficients() for n, c in cams.items()}, target.pattern, target.square_m)
    if est is not None and est.metres_per_unit is not None:
        return est
    reason = (est.detail["reason"] if est is not None else
              f"the {target.pattern[0] + 1}x{target.pattern[1] + 1}-square checkerboard was found in "
              f"{len(corners)} registered frames (need 3)")
    truth = session_truth(session)
    if truth is None:
        return ScaleEstimate(None, "none", {"reason": reason})
    k = recovered.registered
    est = scale_from_truth(np.stack([recovered.c2w(i) for i in k]),
                           np.stack([truth.rgb_pose(session.rgb[selected[i].pair.rgb_index]) for i in k]))
    est.detail["reason"] = reason
    return est
