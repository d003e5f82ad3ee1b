"""Camera poses: interpolation in time, similarity alignment to a reference, pose errors.

All poses are (4, 4) float64 camera-to-world with OpenCV camera axes (x right, y down, z
forward) unless a name says otherwise.
"""
from __future__ import annotations

import numpy as np


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> unit quaternion (w, x, y, z) with w >= 0."""
    m = np.asarray(r, np.float64)
    t = np.trace(m)
    if t > 0:
        s = 2 * np.sqrt(1 + t)
        q = np.array([s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        q = np.empty(4)
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = s / 4
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions, a in [0, 1] (short way round)."""
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    th = np.arccos(d)
    return (np.sin((1 - a) * th) * q0 + np.sin(a * th) * q1) / np.sin(th)


def interpolate_pose(times: np.ndarray, c2ws: np.ndarray, t: float) -> np.ndarray:
    """Pose at time t from poses (K, 4, 4) at sorted `times` (K,): slerp of rotation and linear
    position between the two around t; outside the span, the nearest end pose (no extrapolation)."""
    times = np.asarray(times, np.float64)
    if t <= times[0]:
        return np.array(c2ws[0], np.float64)
    if t >= times[-1]:
        return np.array(c2ws[-1], np.float64)
    j = int(np.searchsorted(times, t, side="right"))
    a = (t - times[j - 1]) / (times[j] - times[j - 1])
    out = np.eye(4)
    out[:3, :3] = matrix_from_quat(slerp(quat_from_matrix(c2ws[j - 1][:3, :3]),
                                         quat_from_matrix(c2ws[j][:3, :3]), a))
    out[:3, 3] = (1 - a) * c2ws[j - 1][:3, 3] + a * c2ws[j][:3, 3]
    return out


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising |s R src + t - dst|^2 for points (N, 3), N >= 3."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    r = u @ sign @ vt
    s = float(np.trace(np.diag(d) @ sign) / (a ** 2).sum() * len(src))
    return s, r, mu_d - s * r @ mu_s


def apply_similarity(s: float, r: np.ndarray, t: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """A camera-to-world pose moved by x -> s R x + t (rotation part stays orthonormal)."""
    out = np.eye(4)
    out[:3, :3] = r @ c2w[:3, :3]
    out[:3, 3] = s * r @ c2w[:3, 3] + t
    return out


def rotation_angle_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


def pose_errors(estimated: np.ndarray, truth: np.ndarray) -> dict:
    """Align estimated poses (K, 4, 4) to the truth (K, 4, 4) by a similarity fitted on camera
    centres, then per-pose rotation error (deg) and position error (truth units)."""
    s, r, t = umeyama(estimated[:, :3, 3], truth[:, :3, 3])
    aligned = np.stack([apply_similarity(s, r, t, c) for c in estimated])
    rot = np.array([rotation_angle_deg(a[:3, :3].T @ g[:3, :3]) for a, g in zip(aligned, truth)])
    pos = np.linalg.norm(aligned[:, :3, 3] - truth[:, :3, 3], axis=1)
    return {"scale": s, "similarity": (s, r, t), "rotation_deg": rot, "position": pos, "aligned": aligned}


def path_jitter_deg(times: np.ndarray, c2ws: np.ndarray) -> np.ndarray:
    """(K-2,) rotation (deg) between each interior pose of a time-ordered path (K, 4, 4) and the
    pose slerped from its two neighbours. A handheld path is smooth at video rates (about 0.1 deg
    here on good reconstructions at 0.1 s spacing); noisy SfM poses jitter by far more."""
    out = []
    for i in range(1, len(times) - 1):
        p = interpolate_pose(times[[i - 1, i + 1]], c2ws[[i - 1, i + 1]], times[i])
        out.append(rotation_angle_deg(p[:3, :3].T @ c2ws[i][:3, :3]))
    return np.array(out)
