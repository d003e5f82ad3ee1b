"""The simulated handheld rig: an iPhone-like RGB camera and a FLIR A700-like thermal camera.

Numbers follow the DynamicRGBT-Scenes rigs: FLIR A700 640x480 at 30 Hz, 24 x 18 degree field of
view, -20..120 C range, ~40 mK NETD, TemperatureLinear10mK counts; iPhone video cropped and
downsampled to 640x480. The thermal camera sits a few centimetres to the right of the phone,
toed in so both look at the same spot about 0.65 m away.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rig.sim.camera import Intrinsics, rotation

REFERENCE_SIZE = (640, 480)


def _thermal_from_rgb() -> np.ndarray:
    """(4, 4) transform taking RGB-camera coordinates to thermal-camera coordinates."""
    rgb_from_thermal = np.eye(4)
    rgb_from_thermal[:3, :3] = (rotation("y", np.radians(-3.0)) @ rotation("x", np.radians(0.4))
                                @ rotation("z", np.radians(0.3)))
    rgb_from_thermal[:3, 3] = [0.04, 0.004, -0.006]
    return np.linalg.inv(rgb_from_thermal)


@dataclass(frozen=True)
class RigConfig:
    """Cameras of one rig; intrinsics at REFERENCE_SIZE (use `Intrinsics.scaled` for others)."""

    rgb: Intrinsics = Intrinsics.from_fov(*REFERENCE_SIZE, hfov_deg=42.0)
    thermal: Intrinsics = Intrinsics.from_fov(*REFERENCE_SIZE, hfov_deg=24.0, vfov_deg=18.0)
    thermal_from_rgb: np.ndarray = field(default_factory=_thermal_from_rgb)
    netd_k: float = 0.04             # thermal temporal noise (1 sigma)
    thermal_scale_k: float = 0.01    # TemperatureLinear10mK: kelvin per count
    thermal_range_k: tuple[float, float] = (253.15, 393.15)  # the A700's -20..120 C
    fps: float = 30.0

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(np.linalg.inv(self.thermal_from_rgb)[:3, 3]))
