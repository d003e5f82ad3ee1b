"""Handheld rig motion: a slow sweep around the table plus seeded hand shake.

Rig 0 sweeps +-50 degrees of azimuth while its elevation drifts between about 25 and 49
degrees; rig 1 sweeps a narrower arc (-15..35 degrees) at 40-48 degrees in the opposite phase.
At every instant the two rigs see the scene from different sides, but over the sequence rig 0
covers every direction rig 1 looks from, so rig 1 (the held-out test camera) asks a model for
novel views *within* the captured coverage, as the Nerfies/HyperNeRF vrig protocol intends,
not for extrapolation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.sim.camera import look_at

TARGET = np.array([0.0, 0.0, 0.03])


@dataclass(frozen=True)
class HandheldPath:
    """Camera-to-world of a rig's RGB camera over time (seconds)."""

    azimuth_deg: float          # centre of the sweep; 0 = standing at -y looking towards +y
    sweep_deg: float            # amplitude of the sweep
    elevation_deg: float
    elevation_sweep_deg: float  # slow drift of elevation, period 0.7 of the azimuth sweep
    radius_m: float
    phase: float                # +1 or -1: direction of the sweep
    period_s: float             # one full back-and-forth sweep
    shake_m: float              # amplitude of positional hand shake
    shake_freqs: np.ndarray     # (3, 3) Hz per axis and component
    shake_phases: np.ndarray    # (3, 3) radians
    target: tuple[float, float, float] = tuple(TARGET)   # the point the rig keeps in view

    @classmethod
    def for_rig(cls, rig: int, seed: int, period_s: float, shake: float) -> "HandheldPath":
        rng = np.random.default_rng([seed, 0x5A4E, rig])
        base = {0: (0.0, 50.0, 37.0, 12.0, 0.60, 1.0), 1: (10.0, 25.0, 44.0, 4.0, 0.55, -1.0)}[rig]
        return cls(*base, period_s=period_s, shake_m=0.003 * shake,
                   shake_freqs=rng.uniform(0.3, 1.8, size=(3, 3)),
                   shake_phases=rng.uniform(0, 2 * np.pi, size=(3, 3)))

    def _shake(self, t: float) -> np.ndarray:
        """(3,) smooth pseudo-random offsets in [-1, 1]-ish, one per axis."""
        return np.sin(2 * np.pi * self.shake_freqs * t + self.shake_phases).sum(axis=1) / 3

    def c2w(self, t: float) -> np.ndarray:
        """(4, 4) float64 OpenCV camera-to-world at time t seconds."""
        s = self.phase * np.sin(2 * np.pi * t / self.period_s)
        az = np.radians(self.azimuth_deg + self.sweep_deg * s)
        el = np.radians(self.elevation_deg + self.elevation_sweep_deg * np.sin(2 * np.pi * t / (0.7 * self.period_s)))
        target = np.asarray(self.target, float)
        eye = target + self.radius_m * np.array([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az),
                                                 np.sin(el)])
        shake = self._shake(t)
        eye = eye + self.shake_m * shake
        aim = target + 2.0 * self.shake_m * np.roll(shake, 1)
        return look_at(eye, aim, roll_rad=np.radians(1.5) * shake[2] * self.shake_m / 0.003)
