"""Analytic shapes in their local frames: ray intersection, normals, texture coordinates.

All rays of a pinhole camera share one origin, so `intersect(origin, dirs)` takes the local
origin (3,) and local directions (..., 3) and returns the ray parameter t (...,) with inf for
a miss. Directions are not normalised: with camera directions of z = 1, t is the camera depth.
Texture coordinates are in metres on the surface, so a texture's texel size fixes its scale.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEAR = 1e-3  # metres; hits closer than this along the ray are ignored


def _first_positive(t_near: np.ndarray, t_far: np.ndarray) -> np.ndarray:
    """The nearer root in front of the origin, inf if both are behind (or NaN for a miss)."""
    t = np.where(t_near > NEAR, t_near, t_far)
    return np.where(t > NEAR, t, np.inf).astype(np.float32)


@dataclass(frozen=True)
class Sphere:
    radius: float

    @property
    def bounding_radius(self) -> float:
        return self.radius

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        a = np.einsum("...i,...i->...", d, d)
        b = d @ o.astype(np.float32)
        c = np.float32(o @ o - self.radius ** 2)
        disc = b * b - a * c
        with np.errstate(invalid="ignore"):
            root = np.sqrt(disc)
        return _first_positive((-b - root) / a, (-b + root) / a)

    def normal(self, p: np.ndarray) -> np.ndarray:
        return p / self.radius

    def uv(self, p: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Longitude/latitude scaled to metres along the equator/meridian."""
        lon = np.arctan2(p[:, 1], p[:, 0])
        lat = np.arccos(np.clip(p[:, 2] / self.radius, -1, 1))
        return np.stack([lon * self.radius, lat * self.radius], axis=1)

    def contains(self, p: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """(N,) whether local points p (N, 3) lie inside the shape grown by tol."""
        return np.linalg.norm(p, axis=1) < self.radius + tol

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        v = rng.normal(size=(n, 3))
        return self.radius * v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(frozen=True)
class Box:
    """Axis-aligned box centred on the local origin with half extents (hx, hy, hz)."""

    half: tuple[float, float, float]
    inside: bool = False  # True: seen from inside (a room); hits are the far walls

    @property
    def bounding_radius(self) -> float:
        return float(np.linalg.norm(self.half))

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Slab test, one axis at a time (few full-size temporaries: this is the hot loop)."""
        t_enter = np.full(d.shape[:-1], -np.inf, np.float32)
        t_exit = np.full(d.shape[:-1], np.inf, np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis in range(3):
                da = d[..., axis]
                far = np.copysign(np.float32(self.half[axis]), da)
                inv = np.float32(1.0) / da
                # fmax/fmin skip the NaN of 0 * inf (a ray lying in a face plane)
                np.fmin(t_exit, (far - np.float32(o[axis])) * inv, out=t_exit)
                if not self.inside:
                    np.fmax(t_enter, (-far - np.float32(o[axis])) * inv, out=t_enter)
        if self.inside:
            return np.where(t_exit > NEAR, t_exit, np.inf).astype(np.float32)
        hit = (t_exit >= t_enter) & (t_enter > NEAR)
        return np.where(hit, t_enter, np.inf).astype(np.float32)

    def normal(self, p: np.ndarray) -> np.ndarray:
        rel = np.abs(p) / np.asarray(self.half)
        axis = np.argmax(rel, axis=1)
        n = np.zeros_like(p)
        n[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis])
        return -n if self.inside else n

    def uv(self, p: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Planar projection along the face normal; faces get disjoint texture regions."""
        axis = np.argmax(np.abs(n), axis=1)
        u = np.where(axis == 0, p[:, 1], p[:, 0])
        v = np.where(axis == 2, p[:, 1], p[:, 2])
        offset = (axis * 2 + (n[np.arange(len(n)), axis] > 0)) * 1.7  # face id -> texture region
        return np.stack([u + offset, v], axis=1)

    def contains(self, p: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """(N,) whether local points p (N, 3) lie inside the box grown by tol."""
        return np.all(np.abs(p) < np.asarray(self.half) + tol, axis=1)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Area-uniform points on the six faces."""
        h = np.asarray(self.half)
        areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]]).repeat(2)
        face = rng.choice(6, size=n, p=areas / areas.sum())
        p = rng.uniform(-1, 1, size=(n, 3)) * h
        axis, sign = face // 2, np.where(face % 2 == 0, -1.0, 1.0)
        p[np.arange(n), axis] = sign * h[axis]
        return p


@dataclass(frozen=True)
class Cylinder:
    """Capped cylinder of `radius` along local +z from z = 0 to z = `height`."""

    radius: float
    height: float

    @property
    def bounding_radius(self) -> float:
        return float(np.hypot(self.radius, self.height))

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        o32 = o.astype(np.float32)
        dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
        a = dx * dx + dy * dy
        b = dx * o32[0] + dy * o32[1]
        c = np.float32(o[0] ** 2 + o[1] ** 2 - self.radius ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            root = np.sqrt(b * b - a * c)
            t_side = _first_positive((-b - root) / a, (-b + root) / a)
            z = o32[2] + t_side * dz
            t_side = np.where((z >= 0) & (z <= self.height), t_side, np.inf)
            best = t_side
            for z_cap in (0.0, self.height):
                t_cap = (np.float32(z_cap) - o32[2]) / dz
                x, y = o32[0] + t_cap * dx, o32[1] + t_cap * dy
                ok = (t_cap > NEAR) & (x * x + y * y <= self.radius ** 2)
                best = np.where(ok & (t_cap < best), t_cap, best)
        return best.astype(np.float32)

    def normal(self, p: np.ndarray) -> np.ndarray:
        eps = 1e-4 + 1e-3 * self.radius
        n = np.zeros_like(p)
        r = np.hypot(p[:, 0], p[:, 1])
        side = r >= self.radius - eps
        n[side, :2] = p[side, :2] / np.maximum(r[side, None], 1e-12)
        n[~side, 2] = np.where(p[~side, 2] > self.height / 2, 1.0, -1.0)
        return n

    def uv(self, p: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Sides: arc length and height; caps: planar x, y shifted off the side region."""
        side = np.abs(n[:, 2]) < 0.5
        arc = np.arctan2(p[:, 1], p[:, 0]) * self.radius
        u = np.where(side, arc, p[:, 0] + 4 * self.radius)
        v = np.where(side, p[:, 2], p[:, 1] + self.height + 2 * self.radius)
        return np.stack([u, v], axis=1)

    def contains(self, p: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """(N,) whether local points p (N, 3) lie inside the cylinder grown by tol."""
        r = np.hypot(p[:, 0], p[:, 1])
        return (r < self.radius + tol) & (p[:, 2] > -tol) & (p[:, 2] < self.height + tol)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        side_area = 2 * np.pi * self.radius * self.height
        cap_area = np.pi * self.radius ** 2
        on_side = rng.uniform(size=n) < side_area / (side_area + 2 * cap_area)
        phi = rng.uniform(0, 2 * np.pi, size=n)
        r = np.where(on_side, self.radius, self.radius * np.sqrt(rng.uniform(size=n)))
        z = np.where(on_side, rng.uniform(0, self.height, size=n),
                     self.height * (rng.uniform(size=n) < 0.5))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
