"""The ray caster: first hits of pinhole-camera rays against posed analytic shapes.

This is the simulator's own renderer (numpy + OpenCV only), deliberately independent of the
Gaussian rasterizer it is used to grade. Each instance is intersected only with the rays
inside the screen rectangle of its bounding sphere, so small objects cost little.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

from rig.sim.camera import pixel_directions
from rig.sim.shapes import Box, Cylinder, Sphere

Shape = Union[Sphere, Box, Cylinder]


@dataclass
class Instance:
    """A shape placed in the world at one instant, with its surface appearance and temperature.

    `albedo(p, n)` and `temperature(p)` take local hit points p (N, 3) and local normals n (N, 3)
    and return linear RGB albedo (N, 3) and kelvin (N,).
    """

    name: str
    shape: Shape
    rotation: np.ndarray          # (3, 3) local -> world
    position: np.ndarray          # (3,) local origin in world
    albedo: Callable[[np.ndarray, np.ndarray], np.ndarray]
    temperature: Callable[[np.ndarray], np.ndarray]
    label: int = 0                # object id in mask images; 0: scenery, not an object
    emissive: bool = False        # albedo is radiance as seen (a sky), not lit by the lights

    @property
    def is_axis_aligned(self) -> bool:
        """Identity rotation: local directions are world directions (skips a matmul per ray)."""
        return bool(np.array_equal(self.rotation, np.eye(3)))

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """World centre (3,) and radius of a sphere enclosing the shape."""
        if isinstance(self.shape, Cylinder):
            center = np.array([0, 0, self.shape.height / 2])
            radius = float(np.hypot(self.shape.radius, self.shape.height / 2))
        else:
            center, radius = np.zeros(3), self.shape.bounding_radius
        return self.rotation @ center + self.position, radius


@dataclass
class Hits:
    """First hits of an (Hs, Ws) grid of sample rays (Hs = height * ss)."""

    depth: np.ndarray       # (Hs, Ws) float32 camera z-depth, inf where nothing was hit
    ids: np.ndarray         # (Hs, Ws) int16 index into the instance list, -1 for no hit
    dirs: np.ndarray        # (Hs, Ws, 3) float32 world directions with camera z = 1
    origin: np.ndarray      # (3,) float64 camera centre


def _sample_rect(inst: Instance, w2c: np.ndarray, fx, fy, cx, cy, ws: int, hs: int,
                 ss: int) -> tuple[int, int, int, int]:
    """Sample-grid rectangle (r0, r1, c0, c1) that contains the instance's projection."""
    center, radius = inst.bounding_sphere()
    c = w2c[:3, :3] @ center + w2c[:3, 3]
    if c[2] - radius < 1e-2:  # the sphere reaches behind the camera: test every ray
        return 0, hs, 0, ws
    corners = c + radius * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                     for sz in (-1, 1)])
    u = (fx * corners[:, 0] / corners[:, 2] + cx) * ss
    v = (fy * corners[:, 1] / corners[:, 2] + cy) * ss
    c0, c1 = int(np.floor(u.min() - 1)), int(np.ceil(u.max() + 1))
    r0, r1 = int(np.floor(v.min() - 1)), int(np.ceil(v.max() + 1))
    return max(r0, 0), min(r1, hs), max(c0, 0), min(c1, ws)


def cast(instances: list[Instance], c2w: np.ndarray, fx: float, fy: float, cx: float,
         cy: float, width: int, height: int, ss: int) -> Hits:
    """Nearest hit per sample ray for an OpenCV camera c2w (4, 4) with ss x ss samples/pixel."""
    cam_dirs = pixel_directions(fx, fy, cx, cy, width, height, ss)
    dirs = cam_dirs @ c2w[:3, :3].T.astype(np.float32)
    hs, ws = dirs.shape[:2]
    origin = c2w[:3, 3].astype(np.float64)
    w2c = np.linalg.inv(c2w)
    depth = np.full((hs, ws), np.inf, np.float32)
    ids = np.full((hs, ws), -1, np.int16)
    for k, inst in enumerate(instances):
        r0, r1, c0, c1 = _sample_rect(inst, w2c, fx, fy, cx, cy, ws, hs, ss)
        if r1 <= r0 or c1 <= c0:
            continue
        local_o = inst.rotation.T @ (origin - inst.position)
        local_d = dirs[r0:r1, c0:c1]
        if not inst.is_axis_aligned:
            local_d = local_d @ inst.rotation.astype(np.float32)
        t = inst.shape.intersect(local_o, local_d)
        closer = t < depth[r0:r1, c0:c1]
        depth[r0:r1, c0:c1][closer] = t[closer]
        ids[r0:r1, c0:c1][closer] = k
    return Hits(depth, ids, dirs, origin)


def surface_points(hits: Hits, inst: Instance, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat sample indices (N,), local points (N, 3) and local normals (N, 3) where instance k won."""
    idx = np.flatnonzero(hits.ids.ravel() == k)
    d = hits.dirs.reshape(-1, 3)[idx]
    if not inst.is_axis_aligned:
        d = d @ inst.rotation.astype(np.float32)
    local_o = (inst.rotation.T @ (hits.origin - inst.position)).astype(np.float32)
    local = local_o + hits.depth.ravel()[idx, None] * d
    return idx, local, inst.shape.normal(local)


def shade_temperature(hits: Hits, instances: list[Instance], background_k: float) -> np.ndarray:
    """Kelvin (Hs, Ws) float32 of the first surface along each sample ray."""
    out = np.full(hits.ids.size, background_k, np.float32)
    for k, inst in enumerate(instances):
        idx, p, _ = surface_points(hits, inst, k)
        if len(idx):
            out[idx] = inst.temperature(p)
    return out.reshape(hits.ids.shape)


def shade_rgb(hits: Hits, instances: list[Instance], lights: list[tuple[np.ndarray, float]],
              ambient: float) -> np.ndarray:
    """Linear radiance (Hs, Ws, 3) float32: albedo x (ambient + sum of Lambert terms)."""
    out = np.zeros((hits.ids.size, 3), np.float32)
    for k, inst in enumerate(instances):
        idx, p, n = surface_points(hits, inst, k)
        if not len(idx):
            continue
        if inst.emissive:
            out[idx] = inst.albedo(p, n)
            continue
        n_world = n if inst.is_axis_aligned else n @ inst.rotation.T.astype(np.float32)
        irradiance = np.full(len(idx), ambient, np.float32)
        for direction, strength in lights:
            irradiance += np.float32(strength) * np.maximum(n_world @ direction.astype(np.float32), 0)
        out[idx] = inst.albedo(p, n) * irradiance[:, None]
    return out.reshape(*hits.ids.shape, 3)


def label_image(hits: Hits, instances: list[Instance], ss: int) -> np.ndarray:
    """Object labels (H, W) uint8: per pixel the label covering most of its ss x ss samples (a
    tie goes to an object over no object). Rays that hit nothing are label 0."""
    labels = np.array([inst.label for inst in instances] + [0], np.int32)
    per_sample = labels[hits.ids.astype(np.int32)]            # id -1 -> the trailing 0
    h, w = per_sample.shape[0] // ss, per_sample.shape[1] // ss
    blocks = per_sample.reshape(h, ss, w, ss)
    present = np.unique(per_sample)
    if len(present) == 1:
        return np.full((h, w), present[0], np.uint8)
    counts = np.stack([(blocks == lab).sum(axis=(1, 3)) + 0.5 * (lab > 0) for lab in present], -1)
    return present[counts.argmax(-1)].astype(np.uint8)
