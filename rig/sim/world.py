"""The simulated dynamic RGB-thermal world: a scripted scene, two handheld rigs, two sensors.

Time: the script lasts `duration_s`; any other time is reflected back into it (t -> 2D - t
after the end, ping-pong), so poses, motion and temperatures stay continuous for a live
stream that runs longer than the script.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from rig.sim import raycast, sensors
from rig.sim.camera import box_downsample
from rig.sim.rig_config import RigConfig
from rig.sim.family import FAMILY_VARIANTS, FamilyScene, case_of
from rig.sim.tabletop import DURATION_S, VARIANTS, AMBIENT_K, TableTopScene
from rig.sim.trajectory import HandheldPath

KEY_LIGHT = (np.array([-0.4, -0.5, 1.0]) / np.linalg.norm([-0.4, -0.5, 1.0]), 0.75)
FILL_LIGHT = (np.array([0.6, 0.3, 0.6]) / np.linalg.norm([0.6, 0.3, 0.6]), 0.25)
AMBIENT_LIGHT = 0.3


def supersampling(width: int, height: int) -> int:
    """Samples per pixel side: 3 x 3 for small frames, 2 x 2 from 320 pixels wide (speed)."""
    return 2 if max(width, height * 4 / 3) >= 320 else 3


class World:
    """A scene of one variant seen by two rigs. Build with `make_world`."""

    def __init__(self, variant: str, seed: int, rig_config: RigConfig | None = None,
                 scene=None):
        """`scene` (anything with `settings` and `instances(t)`, e.g. a calibration target)
        replaces the table-top scene of `variant`; a scene may bring its own `paths` (the two
        rigs) and `duration_s`."""
        if variant not in VARIANTS + FAMILY_VARIANTS:
            raise ValueError(f"unknown variant {variant!r}; choose one of {', '.join(VARIANTS + FAMILY_VARIANTS)}")
        self.variant, self.seed = variant, int(seed)
        if scene is None:
            case = case_of(variant)
            scene = FamilyScene.build(case, self.seed) if case else TableTopScene.build(variant, self.seed)
        self.scene = scene
        self.settings = self.scene.settings
        self.duration_s = getattr(self.scene, "duration_s", DURATION_S)
        self.rig_config = rig_config or getattr(self.scene, "rig_config", None) or RigConfig()
        period = self.duration_s / self.settings.camera_speed
        self.paths = getattr(self.scene, "paths", None) or [
            HandheldPath.for_rig(r, self.seed, period, self.settings.shake) for r in range(2)]
        self._range_k: tuple[float, float] | None = None

    # ------------------------------------------------------------------------------- time
    def scene_time(self, time_s: float) -> float:
        """Reflect any time into [0, duration_s] (ping-pong)."""
        phase = float(time_s) % (2 * self.duration_s)
        return phase if phase <= self.duration_s else 2 * self.duration_s - phase

    # ------------------------------------------------------------------------------ poses
    def rig_pose(self, rig: int, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(c2w_rgb, c2w_thermal): (4, 4) float64 OpenCV camera-to-world of rig 0 or 1."""
        if rig not in (0, 1):
            raise ValueError(f"rig must be 0 or 1, got {rig}")
        c2w_rgb = self.paths[rig].c2w(self.scene_time(time_s))
        return c2w_rgb, c2w_rgb @ np.linalg.inv(self.rig_config.thermal_from_rgb)

    # ---------------------------------------------------------------------------- renders
    def _cast(self, c2w, fx, fy, cx, cy, width, height, time_s, ss):
        instances = self.scene.instances(self.scene_time(time_s))
        c2w = np.asarray(c2w, np.float64)
        return instances, raycast.cast(instances, c2w, fx, fy, cx, cy, int(width), int(height), ss)

    @staticmethod
    def _radiance(instances, hits, ss: int) -> np.ndarray:
        return box_downsample(raycast.shade_rgb(hits, instances, [KEY_LIGHT, FILL_LIGHT], AMBIENT_LIGHT), ss)

    @staticmethod
    def _kelvin(instances, hits, ss: int) -> np.ndarray:
        return box_downsample(raycast.shade_temperature(hits, instances, AMBIENT_K), ss)

    def render_linear_rgb(self, c2w, fx, fy, cx, cy, width, height, time_s) -> np.ndarray:
        """Noise-free, anti-aliased linear radiance (H, W, 3) float64 before the phone sensor."""
        ss = supersampling(width, height)
        return self._radiance(*self._cast(c2w, fx, fy, cx, cy, width, height, time_s, ss), ss)

    def render_rgb(self, c2w, fx, fy, cx, cy, width, height, time_s,
                   rng: np.random.Generator | None = None) -> np.ndarray:
        """uint8 (H, W, 3) sRGB with the variant's lighting; phone noise when rng is given."""
        radiance = self.render_linear_rgb(c2w, fx, fy, cx, cy, width, height, time_s)
        return sensors.phone_rgb(radiance, self.settings.light, self.settings.gain, rng)

    def render_temperature(self, c2w, fx, fy, cx, cy, width, height, time_s) -> np.ndarray:
        """Noise-free, anti-aliased surface temperature (H, W) float64 kelvin."""
        ss = supersampling(width, height)
        return self._kelvin(*self._cast(c2w, fx, fy, cx, cy, width, height, time_s, ss), ss)

    def render_frame(self, modality: str, c2w, fx, fy, cx, cy, width, height, time_s,
                     rng: np.random.Generator | None, scale_k: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
        """What a sensor records plus the object labels, from one ray cast: (uint8 (H, W, 3) sRGB
        or uint16 (H, W) thermal counts, uint8 (H, W) labels; see raycast.label_image)."""
        ss = supersampling(width, height)
        instances, hits = self._cast(c2w, fx, fy, cx, cy, width, height, time_s, ss)
        if modality == "rgb":
            pixels = sensors.phone_rgb(self._radiance(instances, hits, ss), self.settings.light,
                                       self.settings.gain, rng)
        else:
            pixels = self.thermal_counts(self._kelvin(instances, hits, ss), rng, scale_k)
        return pixels, raycast.label_image(hits, instances, ss)

    def mask_labels(self) -> dict[int, dict]:
        """{label: {"name", "moving"}} of the scene's objects (empty for a scene without them)."""
        labels = getattr(self.scene, "mask_labels", None)
        return labels() if labels else {}

    def render_depth(self, c2w, fx, fy, cx, cy, width, height, time_s) -> np.ndarray:
        """Camera z-depth (H, W) float64 metres at pixel centres (no anti-aliasing)."""
        _, hits = self._cast(c2w, fx, fy, cx, cy, width, height, time_s, 1)
        return hits.depth.astype(np.float64)

    def thermal_counts(self, kelvin: np.ndarray, rng: np.random.Generator | None,
                       scale_k: float = 0.01) -> np.ndarray:
        """uint16 FLIR TemperatureLinear counts with the rig's NETD noise; 0 = no measurement."""
        return sensors.thermal_counts(kelvin, rng, scale_k, self.rig_config.netd_k)

    # ----------------------------------------------------------------------- ground truth
    @property
    def temperature_range_k(self) -> tuple[float, float]:
        """(min, max) kelvin that surfaces reach during the script at full thermal contrast.

        This is the span a thermographer would set for the table-top scene; flat-thermal keeps
        the default's span, so its frames really are near-uniform once normalised with it.
        """
        if self._range_k is None:
            full = replace(self.scene, settings=replace(self.settings, thermal_contrast=1.0))
            rng = np.random.default_rng(0)
            lo, hi = np.inf, -np.inf
            for t in np.linspace(0, self.duration_s, 41):
                for inst in full.instances(t):
                    kelvin = inst.temperature(inst.shape.sample_surface(2000, rng))
                    lo, hi = min(lo, float(kelvin.min())), max(hi, float(kelvin.max()))
            margin = 0.03 * (hi - lo)
            self._range_k = (round(lo - margin, 1), round(hi + margin, 1))
        return self._range_k

    def visible_points(self, times: list[float], per_view: int, rng: np.random.Generator,
                       rig: int = 0, size: tuple[int, int] = (160, 120),
                       noise_m: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
        """An SfM-like sparse cloud: points on surfaces seen by `rig`'s RGB camera.

        For each time, `per_view` random pixels are back-projected with the true depth and
        coloured with the noise-free render, then jittered by `noise_m`. Returns xyz (M, 3)
        float64 and rgb (M, 3) uint8.
        """
        intr = self.rig_config.rgb.scaled(*size)
        xyz, rgb = [], []
        for t in times:
            c2w, _ = self.rig_pose(rig, t)
            k = (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height, t)
            depth = self.render_depth(c2w, *k)
            color = self.render_rgb(c2w, *k)
            rows = rng.integers(0, intr.height, per_view)
            cols = rng.integers(0, intr.width, per_view)
            z = depth[rows, cols]
            near = z < getattr(self.scene, "max_point_depth_m", np.inf)   # no points on a sky
            rows, cols, z = rows[near], cols[near], z[near]
            cam = np.stack([(cols + 0.5 - intr.cx) / intr.fx * z, (rows + 0.5 - intr.cy) / intr.fy * z,
                            z], axis=1)
            xyz.append(cam @ c2w[:3, :3].T + c2w[:3, 3] + rng.normal(0, noise_m, cam.shape))
            rgb.append(color[rows, cols])
        return np.concatenate(xyz), np.concatenate(rgb)


def make_world(variant: str = "default", seed: int = 0) -> World:
    """The table-top world of one of VARIANTS; the seed fixes textures and hand shake."""
    return World(variant, seed)
