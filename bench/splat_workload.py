"""The rasterizer benchmark workload (as /work/shared/research/cpu_peers_facts.md section 0).

Surface samples of a textured unit sphere standing on a textured plane disc (60% / 40%),
isotropic Gaussians with scale = K x mean distance to the 3 nearest neighbours (OpenSplat's
initialisation; K=1 "fresh init", K=3 "denser overlap, trained-like"), opacity 0.5, and views on
a circle of radius 4 looking at the origin, 320x240, fx=fy=300.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Workload:
    means: torch.Tensor       # (N,3)
    quats: torch.Tensor       # (N,4)
    log_scales: torch.Tensor  # (N,3)
    opacities: torch.Tensor   # (N,)
    colors: torch.Tensor      # (N,3)
    viewmats: list            # of (4,4) world-to-camera, OpenCV
    fx: float = 300.0
    fy: float = 300.0
    cx: float = 160.0
    cy: float = 120.0
    width: int = 320
    height: int = 240


def _texture(p: np.ndarray) -> np.ndarray:
    """(M,3) points -> (M,3) colours in [0,1]: a smooth checker-like pattern."""
    s = np.sin(3.0 * p[:, 0]) * np.sin(3.0 * p[:, 1]) * np.sin(3.0 * p[:, 2] + 1.0)
    return np.stack([0.5 + 0.4 * s, 0.5 + 0.3 * np.cos(2 * p[:, 0]), 0.5 - 0.4 * s], 1).clip(0, 1)


def _mean_knn_distance(points: np.ndarray, k: int = 3) -> np.ndarray:
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points).query(points, k=k + 1)
    return dist[:, 1:].mean(1)


def look_at_opencv(campos: np.ndarray, target=np.zeros(3), up=np.array([0.0, 0.0, 1.0])) -> torch.Tensor:
    z = target - campos
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    view = np.eye(4)
    view[:3, :3] = np.stack([x, y, z])
    view[:3, 3] = -view[:3, :3] @ campos
    return torch.tensor(view, dtype=torch.float32)


def make_workload(n: int, scale_k: float = 3.0, opacity: float = 0.5, views: int = 20, seed: int = 0) -> Workload:
    rng = np.random.default_rng(seed)
    n_sphere = int(0.6 * n)
    d = rng.normal(size=(n_sphere, 3))
    sphere = d / np.linalg.norm(d, axis=1, keepdims=True)
    r = 3.0 * np.sqrt(rng.uniform(size=n - n_sphere))
    phi = rng.uniform(0, 2 * math.pi, size=n - n_sphere)
    plane = np.stack([r * np.cos(phi), r * np.sin(phi), np.full_like(r, -1.0)], 1)
    points = np.concatenate([sphere, plane]) + rng.normal(scale=0.01, size=(n, 3))
    scales = scale_k * _mean_knn_distance(points)
    angles = np.linspace(0, 2 * math.pi, views, endpoint=False)
    viewmats = [look_at_opencv(np.array([4 * math.cos(a), 4 * math.sin(a), 1.5])) for a in angles]
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return Workload(
        means=torch.tensor(points, dtype=torch.float32),
        quats=torch.tensor(quats, dtype=torch.float32),
        log_scales=torch.tensor(np.log(scales)[:, None].repeat(3, 1), dtype=torch.float32),
        opacities=torch.full((n,), opacity, dtype=torch.float32),
        colors=torch.tensor(_texture(points), dtype=torch.float32),
        viewmats=viewmats,
    )
