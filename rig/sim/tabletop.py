"""The scripted table-top scene: what is where, what it looks like and how hot it is, at time t.

World frame: metres, z up, table top at z = 0, the scene centre at the origin. The scene lasts
`DURATION_S`; callers map other times into it (see `World.scene_time`).

Cast (default variant):
- a hot plate switched on at t = 0 (25 -> ~115 C at its coil rings), warming the table around it;
- a mug of hot water cooling (85 -> ~60 C), topped up by a hot stream poured from above at 1.5-4 s;
- an ice pack (9 -> 14 C) pushed back and forth across the table;
- a warm ball (37 C) rolling back and forth;
- a fading warm hand print on the table; a room around it all at ~21 C.
Variants change lighting, speed, temperatures and add an occluding arm (see `VARIANT_SETTINGS`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rig.sim.camera import rotation
from rig.sim.checkerboard import CheckerboardTarget
from rig.sim.raycast import Instance
from rig.sim.shapes import Box, Cylinder, Sphere
from rig.sim.textures import Texture, fbm, patterned_texture, plain_texture, table_texture

DURATION_S = 10.0
C0 = 273.15
AMBIENT_K = C0 + 22.0

VARIANTS = ("default", "dark", "fast", "occlusion", "flat-thermal", "rapid", "target")


@dataclass(frozen=True)
class VariantSettings:
    """How a variant departs from the default scene."""

    light: float = 1.0             # illumination scale reaching the phone sensor
    gain: float = 1.0              # phone gain after the sensor (amplifies noise too)
    object_speed: float = 1.0      # moving objects
    camera_speed: float = 1.0      # handheld rig motion
    shake: float = 1.0             # handheld jitter amplitude
    occluder: bool = False         # an arm reaching across the table at 2.5-7.5 s
    thermal_contrast: float = 1.0  # temperatures pulled towards ambient (flat-thermal)
    rapid: bool = False            # heater toggled and water poured in bursts: step changes
    printed_target: bool = False   # the calibration checkerboard printed on paper, lying on the table


VARIANT_SETTINGS = {
    "default": VariantSettings(),
    "dark": VariantSettings(light=0.05, gain=5.0),
    "fast": VariantSettings(object_speed=3.0, camera_speed=3.0, shake=3.0),
    "occlusion": VariantSettings(occluder=True),
    "flat-thermal": VariantSettings(thermal_contrast=0.03),
    "rapid": VariantSettings(rapid=True),
    "target": VariantSettings(printed_target=True),
}

# Positions on the table (x, y) in metres.
PLATE_XY, PLATE_R, PLATE_H = np.array([-0.08, 0.06]), 0.06, 0.012
MUG_XY, MUG_R, MUG_H = np.array([0.08, 0.08]), 0.04, 0.09
BALL_R = 0.025
ICE_HALF = (0.045, 0.028, 0.011)
HAND_XY = np.array([0.02, -0.13])
STREAM_R, STREAM_TOP = 0.004, 1.2
POURS_DEFAULT = ((1.5, 4.0),)
POURS_RAPID = ((1.0, 1.4), (3.0, 3.3), (5.5, 6.0), (8.0, 8.4))
PLATE_LEVELS_RAPID_C = (100.0, 40.0, 110.0, 35.0, 95.0)  # a new setpoint every 2 s
TABLE_HALF = (0.6, 0.4, 0.015)
TARGET_XY, TARGET_YAW = np.array([-0.075, 0.21]), 0.0   # printed checkerboard ("target" variant)
ROOM_HALF, ROOM_CENTER = (2.5, 2.5, 1.4), np.array([0.0, 0.0, 0.65])


# Object labels in mask images (0: table, room): name -> id; MOVING: the ones that move.
LABELS = {"hot plate": 1, "mug": 2, "ice pack": 3, "ball": 4, "stream": 5, "arm": 6, "printed target": 7}
MOVING = {"ice pack", "ball", "stream", "arm"}


@lru_cache(maxsize=4)
def _textures(seed: int) -> tuple[dict[str, Texture], Texture]:
    """All surface textures of a seed (about 0.4 s to make, so worlds of one seed share them)."""
    rng = np.random.default_rng([seed, 0x7AB1E])
    textures = {
        "table": table_texture(rng),
        "room": plain_texture(rng, (0.55, 0.52, 0.48), contrast=0.25),
        "mug": patterned_texture(rng, base=(0.08, 0.22, 0.55), accent=(0.8, 0.75, 0.6)),
        "ice": patterned_texture(rng, base=(0.15, 0.45, 0.75), accent=(0.9, 0.9, 0.92)),
        "ball": patterned_texture(rng, base=(0.75, 0.12, 0.05), accent=(0.9, 0.8, 0.1)),
        "plate": patterned_texture(rng, base=(0.05, 0.05, 0.055), accent=(0.25, 0.25, 0.25)),
        "arm": plain_texture(rng, (0.55, 0.35, 0.25), contrast=0.15, texel_m=0.001),
        "water": plain_texture(rng, (0.55, 0.65, 0.75), contrast=0.35, texel_m=0.0005),
        "coffee": plain_texture(rng, (0.12, 0.06, 0.03), contrast=0.3, texel_m=0.0005),
    }
    heat_noise = Texture(fbm(400, 600, rng, cell_px=30, octaves=4)[..., None] * 2 - 1, 0.002)
    for texture in (*textures.values(), heat_noise):
        texture.image.flags.writeable = False  # shared between worlds
    return textures, heat_noise


def _smooth_step(x: np.ndarray | float) -> np.ndarray | float:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _sweep(t: float, period: float) -> float:
    """Smooth back-and-forth in [0, 1]: 0 at t = 0, 1 at period/2, 0 at period."""
    return 0.5 - 0.5 * np.cos(2 * np.pi * t / period)


@dataclass
class TableTopScene:
    """The table-top scene of one variant; `instances(t)` poses and heats everything at t."""

    settings: VariantSettings
    textures: dict[str, Texture]
    table_heat_noise: Texture  # (H, W, 1) in [-1, 1]: small temperature texture of the wood

    @classmethod
    def build(cls, variant: str, seed: int) -> "TableTopScene":
        textures, heat_noise = _textures(seed)
        return cls(VARIANT_SETTINGS[variant], textures, heat_noise)

    def mask_labels(self) -> dict[int, dict]:
        """{label: {"name", "moving"}} of the objects this variant has."""
        names = [n for n in LABELS if n != "arm" or self.settings.occluder]
        names = [n for n in names if n != "printed target" or self.settings.printed_target]
        return {LABELS[n]: {"name": n, "moving": n in MOVING} for n in names}

    # ---------------------------------------------------------------- temperature laws (kelvin)
    def _contrast(self, kelvin: np.ndarray | float) -> np.ndarray | float:
        return AMBIENT_K + self.settings.thermal_contrast * (kelvin - AMBIENT_K)

    def pours(self) -> tuple[tuple[float, float], ...]:
        return POURS_RAPID if self.settings.rapid else POURS_DEFAULT

    def plate_k(self, t: float) -> float:
        """Mean plate top temperature: first-order heating towards the setpoint."""
        if not self.settings.rapid:
            return C0 + 25.0 + 85.0 * (1 - np.exp(-t / 3.5))
        level, start_c = int(min(t // 2.0, len(PLATE_LEVELS_RAPID_C) - 1)), 25.0
        if level > 0:
            start_c = PLATE_LEVELS_RAPID_C[level - 1]
        target_c = PLATE_LEVELS_RAPID_C[level]
        return C0 + target_c + (start_c - target_c) * np.exp(-(t - 2.0 * level) / 0.12)

    def water_k(self, t: float) -> float:
        """Mug water: Newton cooling from 85 C plus a jump of mixing heat for every pour."""
        kelvin = AMBIENT_K + (C0 + 85.0 - AMBIENT_K) * np.exp(-t / 30.0)
        jump = 14.0 if self.settings.rapid else 9.0
        for start, end in self.pours():
            mixed = _smooth_step((t - start) / (end - start))
            kelvin += jump * mixed * np.exp(-max(t - end, 0.0) / 30.0)
        return kelvin

    def stream_radius(self, t: float) -> float:
        """Radius of the poured stream (0 when not pouring; opens and closes in 0.1 s)."""
        opening = max((_smooth_step((t - s) / 0.1) * _smooth_step((e - t) / 0.1))
                      for s, e in self.pours())
        return STREAM_R * float(opening)

    # ---------------------------------------------------------------------------- motion laws
    def ice_pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = _sweep(t * self.settings.object_speed, 8.0)
        xy = np.array([-0.10 + 0.18 * s, -0.12 + 0.015 * np.sin(3 * s)])
        yaw = np.radians(15 + 35 * s)
        return rotation("z", yaw), np.array([xy[0], xy[1], ICE_HALF[2]])

    def ball_pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        x = 0.10 - 0.20 * _sweep(t * self.settings.object_speed, 6.0)
        return rotation("y", x / BALL_R), np.array([x, -0.035, BALL_R])

    def arm_tip_x(self, t: float) -> float | None:
        """x of the occluding arm's finger tips (it reaches in from +x), None when out of view."""
        if not self.settings.occluder or not 2.5 <= t <= 7.5:
            return None
        return 0.6 - 0.65 * np.sin(np.pi * (t - 2.5) / 5.0)

    # ------------------------------------------------------------------------------ instances
    def instances(self, t: float) -> list[Instance]:
        """Everything in the scene at scene time t in [0, DURATION_S]."""
        tex = self.textures
        contrast = self._contrast
        ice_r, ice_p = self.ice_pose(t)
        ball_r, ball_p = self.ball_pose(t)
        plate_k, water_k = self.plate_k(t), self.water_k(t)
        identity = np.eye(3)

        room = Box(ROOM_HALF, inside=True)
        out = [
            Instance("room", room, identity, ROOM_CENTER,
                     lambda p, n: tex["room"].sample(room.uv(p, n)),
                     lambda p: contrast(AMBIENT_K - 1.5 + 0.8 * (p[:, 2] + ROOM_HALF[2])
                                        / (2 * ROOM_HALF[2])).astype(np.float32)),
            self._table(t, plate_k, water_k, ice_p, ball_p),
            self._plate(plate_k),
            self._mug(water_k),
            Instance("ice pack", Box(ICE_HALF), ice_r, ice_p,
                     lambda p, n: tex["ice"].sample(Box(ICE_HALF).uv(p, n)),
                     lambda p: contrast(C0 + 9.0 + 5.0 * (1 - np.exp(-t / 20.0))
                                        + 1.5 * np.abs(p[:, 0]) / ICE_HALF[0]
                                        ).astype(np.float32), label=LABELS["ice pack"]),
            Instance("ball", Sphere(BALL_R), ball_r, ball_p,
                     lambda p, n: tex["ball"].sample(Sphere(BALL_R).uv(p, n)),
                     lambda p: contrast(C0 + 37.0 - 2.5 * t / DURATION_S
                                        - 1.0 * p[:, 2] / BALL_R).astype(np.float32), label=LABELS["ball"]),
        ]
        radius = self.stream_radius(t)
        if radius > 1e-4:
            out.append(self._stream(t, radius))
        tip = self.arm_tip_x(t)
        if tip is not None:
            out.append(self._arm(t, tip))
        if self.settings.printed_target:
            out.append(self._printed_target())
        return out

    def _printed_target(self) -> Instance:
        """The `rig calibrate` checkerboard printed on paper (0.5 mm), lying behind the objects:
        a known size in view, for the metric scale of SfM. Paper at the table's temperature."""
        target = CheckerboardTarget(thickness_m=0.0005)
        albedo, _ = target.face_textures()
        half = (*(s / 2 for s in target.size_m), target.thickness_m / 2)
        shape = Box(half)

        def face(p, n):
            out = np.full((len(p), 3), 0.85, np.float32)
            top = n[:, 2] > 0.5
            out[top] = albedo.sample(p[top, :2] + np.array(half[:2]))
            return out

        return Instance("printed target", shape, rotation("z", TARGET_YAW), np.array([*TARGET_XY, half[2]]),
                        face, lambda p: np.full(len(p), AMBIENT_K - 0.3, np.float32),
                        label=LABELS["printed target"])

    def _table(self, t, plate_k, water_k, ice_p, ball_p) -> Instance:
        tex, half = self.textures["table"], TABLE_HALF
        light_dir = np.array([-0.4, -0.5, 1.0])
        # blob shadows of the objects resting on the table: (x, y, radius, height)
        casters = [(*PLATE_XY, PLATE_R, PLATE_H), (*MUG_XY, MUG_R, MUG_H),
                   (*ice_p[:2], 0.04, 2 * ICE_HALF[2]), (*ball_p[:2], BALL_R, 2 * BALL_R)]
        # heat halos: (x, y, width, kelvin above ambient at the centre)
        halos = [(*PLATE_XY, 0.085, 0.35 * (plate_k - AMBIENT_K)),
                 (*MUG_XY, 0.06, 0.15 * (water_k - AMBIENT_K)),
                 (*ice_p[:2], 0.05, -4.0)]
        noise = self.table_heat_noise

        def albedo(p, n):
            top = n[:, 2] > 0.5
            uv = np.where(top[:, None], p[:, :2] + np.array(half[:2]), p[:, [0, 2]] * 3.0)
            color = tex.sample(uv)
            for x, y, r, h in casters:
                sx, sy = x - light_dir[0] / light_dir[2] * h / 2, y - light_dir[1] / light_dir[2] * h / 2
                near = np.flatnonzero((np.abs(p[:, 0] - sx) < 4 * r) & (np.abs(p[:, 1] - sy) < 4 * r))
                d2 = (p[near, 0] - sx) ** 2 + (p[near, 1] - sy) ** 2
                color[near] *= (1 - 0.55 * np.exp(-d2 / (1.3 * r) ** 2))[:, None]
            return color

        def temperature(p):
            kelvin = AMBIENT_K - 0.5 + 0.4 * noise.sample(p[:, :2] + 1.0)[:, 0]
            for x, y, w, dk in halos:
                kelvin = kelvin + dk * np.exp(-((p[:, 0] - x) ** 2 + (p[:, 1] - y) ** 2) / w ** 2)
            hand = ((p[:, 0] - HAND_XY[0]) / 0.045) ** 2 + ((p[:, 1] - HAND_XY[1]) / 0.025) ** 2
            kelvin = kelvin + 7.0 * np.exp(-t / 2.5) * np.exp(-hand ** 2)
            return self._contrast(kelvin).astype(np.float32)

        return Instance("table", Box(half), np.eye(3), np.array([0, 0, -half[2]]), albedo,
                        temperature)

    def _plate(self, plate_k: float) -> Instance:
        tex = self.textures["plate"]
        coil_amp = 0.1 * (plate_k - AMBIENT_K)

        def rings(p):
            r = np.hypot(p[:, 0], p[:, 1])
            return (np.exp(-((r - 0.022) / 0.006) ** 2) + np.exp(-((r - 0.042) / 0.006) ** 2),
                    r)

        def albedo(p, n):
            ring, _ = rings(p)
            base = tex.sample(Cylinder(PLATE_R, PLATE_H).uv(p, n))
            return base * (1 - 0.5 * ring[:, None]) + 0.02 * ring[:, None]

        def temperature(p):
            ring, r = rings(p)
            top = p[:, 2] > PLATE_H - 1e-4
            kelvin = np.where(top, plate_k - 0.15 * (plate_k - AMBIENT_K) * (r / PLATE_R) ** 2
                              + coil_amp * ring,
                              AMBIENT_K + 0.6 * (plate_k - AMBIENT_K) * p[:, 2] / PLATE_H)
            return self._contrast(kelvin).astype(np.float32)

        return Instance("hot plate", Cylinder(PLATE_R, PLATE_H), np.eye(3),
                        np.array([*PLATE_XY, 0.0]), albedo, temperature, label=LABELS["hot plate"])

    def _mug(self, water_k: float) -> Instance:
        tex, coffee = self.textures["mug"], self.textures["coffee"]
        shape = Cylinder(MUG_R, MUG_H)

        def albedo(p, n):
            top = n[:, 2] > 0.5
            out = tex.sample(shape.uv(p, n))
            out[top] = coffee.sample(p[top, :2])
            return out

        def temperature(p):
            top = p[:, 2] > MUG_H - 1e-4
            r = np.hypot(p[:, 0], p[:, 1]) / MUG_R
            wall = AMBIENT_K + (water_k - AMBIENT_K) * (0.55 + 0.3 * p[:, 2] / MUG_H)
            liquid = water_k - 2.0 * r ** 2
            return self._contrast(np.where(top, liquid, wall)).astype(np.float32)

        return Instance("mug", shape, np.eye(3), np.array([*MUG_XY, 0.0]), albedo, temperature,
                        label=LABELS["mug"])

    def _stream(self, t: float, radius: float) -> Instance:
        water = self.textures["water"]
        shape = Cylinder(radius, STREAM_TOP - MUG_H)

        def albedo(p, n):  # streaks that run down the stream
            uv = np.stack([np.arctan2(p[:, 1], p[:, 0]) * STREAM_R, p[:, 2] + 0.8 * t], axis=1)
            return water.sample(uv)

        return Instance("stream", shape, np.eye(3), np.array([*MUG_XY, MUG_H]), albedo,
                        lambda p: self._contrast(C0 + 92.0 + 4.0 * p[:, 2] / shape.height
                                                 ).astype(np.float32), label=LABELS["stream"])

    def _arm(self, t: float, tip_x: float) -> Instance:
        length = 0.7
        skin = self.textures["arm"]
        shape = Cylinder(0.035, length)
        # local +z points along world -x: from the shoulder (out of view) to the finger tips
        to_tip = rotation("y", -np.pi / 2)
        position = np.array([tip_x + length, -0.02 + 0.03 * np.sin(t), 0.12])

        def temperature(p):
            return self._contrast(C0 + 34.0 - 1.5 * np.exp(-((length - p[:, 2]) / 0.05) ** 2)
                                  ).astype(np.float32)

        return Instance("arm", shape, to_tip, position,
                        lambda p, n: skin.sample(shape.uv(p, n)), temperature, label=LABELS["arm"])

