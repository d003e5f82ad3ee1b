"""A prepared dataset as training sees it: cameras, normalised images, time steps, scene extent.

Thermal images are trained as normalised temperature u = (K - K_min) / (K_max - K_min) with the
dataset's ``thermal_range_k``; invalid pixels (count 0) are masked. Images are read lazily through
the dataset's own memory-bounded cache.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from recon.data import Dataset, Frame
from recon.splat.cameras import PinholeCamera as Camera


def camera_of_frame(frame: Frame) -> Camera:
    return Camera(torch.as_tensor(np.asarray(frame.viewmat()), dtype=torch.float32),
                  float(frame.fx), float(frame.fy), float(frame.cx), float(frame.cy),
                  int(frame.width), int(frame.height))


def up_from_cameras(rotations: torch.Tensor) -> torch.Tensor:
    """The world's up (3,) from world-to-camera rotations (V, 3, 3), OpenCV axes (y down).

    A handheld camera is held level: its x axis (row 0) is horizontal however far it looks down,
    while its own up (-row 1) leans towards what it looks at (averaged over a sweep around a
    scene, 20-30 degrees off). So up is the direction most orthogonal to every camera's x axis;
    where those all point alike (no sweep) it is taken within their orthogonal plane, nearest the
    cameras' mean up. Sign: the cameras' mean up. Zeros (unknown) where that estimate is more than
    75 degrees from the cameras' mean up: cameras held on their side (a portrait video whose
    rotation was not applied) would otherwise make a wall the floor."""
    right = rotations[:, 0, :].double()
    mean_up = -rotations[:, 1, :].double().mean(0)
    values, vectors = torch.linalg.eigh(right.T @ right / len(right))
    if float(values[1]) < 0.01:          # x axes within ~6 degrees of one direction: no sweep
        plane = vectors[:, :2]
        up = plane @ (plane.T @ mean_up)
    else:
        up = vectors[:, 0]
    up = up / up.norm().clamp_min(1e-12)
    up = up if float(up @ mean_up) >= 0 else -up
    if float(up @ mean_up) < math.cos(math.radians(75)) * float(mean_up.norm()):
        return torch.zeros(3)
    return up.float()


@dataclass
class View:
    frame: Frame
    camera: Camera
    time: float


class Scene:
    """time_of(frame) -> training time; default the dataset's normalised `time`. Live training
    (`recon.live.follow`) passes timestamp_s / horizon so times stay put while the capture grows."""

    def __init__(self, dataset: Dataset, time_of=None):
        self.dataset = dataset
        self.time_of = time_of or (lambda frame: float(frame.time))
        self.k_min, self.k_max = (float(v) for v in dataset.thermal_range_k)
        self.train = {m: [self._view(f) for f in dataset.split(m, "train")] for m in ("rgb", "thermal")}
        self.test = {m: [self._view(f) for f in dataset.split(m, "test")] for m in ("rgb", "thermal")}
        self.times = sorted({v.time for vs in self.train.values() for v in vs})
        self._by_time = {m: {} for m in ("rgb", "thermal")}
        for m, views in self.train.items():
            for v in views:
                self._by_time[m].setdefault(v.time, []).append(v)

    def _view(self, frame: Frame) -> View:
        return View(frame, camera_of_frame(frame), self.time_of(frame))

    def modalities(self) -> tuple[str, ...]:
        return tuple(m for m in ("rgb", "thermal") if self.train[m])

    def views_at(self, modality: str, time: float) -> list[View]:
        return self._by_time[modality].get(time, [])

    def steps_per_unit_time(self) -> int:
        """Time steps the whole [0, 1] time axis holds at this scene's sampling density: the step
        count for a dataset spanning [0, 1]; more for a live capture covering part of its horizon."""
        n = len(self.times)
        span = self.times[-1] - self.times[0] if n > 1 else 0.0
        return n if span <= 0 else int(round((n - 1) / span)) + 1

    def extent(self) -> float:
        """1.1 x the largest distance of a training camera from their mean (3DGS), floored by the
        spread of the initial points so a nearly static handheld capture keeps sane step sizes."""
        centers = torch.stack([v.camera.center for vs in self.train.values() for v in vs])
        e = 1.1 * float((centers - centers.mean(0)).norm(dim=1).max())
        pts = self.dataset.points_xyz
        if pts is not None and len(pts) > 1:
            p = torch.as_tensor(np.asarray(pts), dtype=torch.float32)
            e = max(e, 0.5 * float((p - p.median(0).values).norm(dim=1).quantile(0.9)))
        return max(e, 1e-3)

    def up(self) -> torch.Tensor:
        """(3,) unit vector: the world's up as the training cameras show it (up_from_cameras)."""
        rotations = torch.stack([v.camera.viewmat[:3, :3] for vs in self.train.values() for v in vs])
        return up_from_cameras(rotations)

    # ------------------------------------------------------------ images
    def normalise_k(self, kelvin: torch.Tensor) -> torch.Tensor:
        return (kelvin - self.k_min) / (self.k_max - self.k_min)

    def kelvin(self, u: torch.Tensor) -> torch.Tensor:
        return u * (self.k_max - self.k_min) + self.k_min

    def target(self, view: View) -> tuple[torch.Tensor, torch.Tensor | None]:
        """RGB: ((H, W, 3) in [0, 1], None). Thermal: ((H, W) normalised temperature, valid (H, W))."""
        img = self.dataset.image(view.frame)
        if view.frame.modality == "rgb":
            return torch.tensor(np.asarray(img), dtype=torch.float32), None
        kelvin, valid = img if isinstance(img, tuple) else (img, np.isfinite(img))
        kelvin = torch.as_tensor(np.nan_to_num(np.asarray(kelvin, dtype=np.float32)))
        valid = torch.as_tensor(np.asarray(valid), dtype=torch.bool)
        return self.normalise_k(kelvin), valid
