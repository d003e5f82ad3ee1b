"""A seeded family of dynamic RGB-thermal scenes: the scenes the defaults are measured on.

The table-top scene (tabletop.py) is one scene; defaults chosen on it are a guess. Each seed here
draws a new scene from the same recipe, and a *case* fixes what is being tested:

- ``inside``: the held-out rig looks from directions the training rig also visits;
- ``outside``: the held-out rig stands 17-45 degrees beyond the training rig's sweep;
- ``fast``: as inside, objects 2.5x faster; ``dark``: as inside, light at 1/8-1/4.

What a seed draws (everything analytic, ray cast, never Gaussians):
- a floor (checkerboard or noise), one to three textured walls, and an open sky (cold in thermal);
- one to three moving objects (ball, box, can) that are hot or cold, heat up or cool down, and
  move on a half circle, a fast straight line (possibly entering or leaving the view), or
  back and forth, while spinning; some have RGB contrast so low that only thermal sees them;
- static objects: a cup of hot liquid cooling, a prop at room temperature, a warm spot on the
  floor that fades;
- two handheld rigs (RGB camera + a thermal camera 4 cm beside it with a narrower field of
  view, fields of view drawn per scene); rig 0 sweeps an arc around the scene 1.2-2 m away,
  rig 1 (held out) is placed by the case.

Every object carries a mask label (`mask_labels()`), so evaluation can grade moving, hot and
static regions apart.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from rig.sim.camera import Intrinsics, rotation
from rig.sim.raycast import Instance
from rig.sim.rig_config import REFERENCE_SIZE, RigConfig
from rig.sim.shapes import Box, Cylinder, Sphere
from rig.sim.tabletop import C0, VariantSettings
from rig.sim.textures import Texture, fbm, patterned_texture, plain_texture
from rig.sim.trajectory import HandheldPath

FAMILY_DURATION_S = 8.0
CASES = ("inside", "outside", "fast", "dark")
VARIANT_PREFIX = "family-"
FAMILY_VARIANTS = tuple(VARIANT_PREFIX + c for c in CASES)
SKY_RADIUS_M = 40.0


# ------------------------------------------------------------------------------ textures
def checker_texture(rng: np.random.Generator, square_m: float, size_squares: int = 24,
                    px_per_square: int = 24) -> Texture:
    """A checkerboard of two random colours, softened by noise so it is not perfectly regular."""
    n = size_squares * px_per_square
    idx = (np.arange(n) // px_per_square) % 2
    board = (idx[:, None] ^ idx[None, :]).astype(np.float32)
    dark = rng.uniform(0.05, 0.3, 3)
    light = rng.uniform(0.55, 0.9, 3)
    img = dark + board[..., None] * (light - dark)
    img *= (0.8 + 0.4 * fbm(n, n, rng, cell_px=px_per_square * 2, octaves=4))[..., None]
    return Texture(np.clip(img, 0.01, 0.95).astype(np.float32), square_m / px_per_square)


def sky_texture(rng: np.random.Generator) -> Texture:
    """Bluish sky with soft clouds, addressed by (azimuth, elevation) in radians * radius."""
    h, w = 128, 512
    clouds = fbm(h, w, rng, cell_px=40, octaves=4)
    base = np.array([0.35, 0.55, 0.85], np.float32) * rng.uniform(0.8, 1.1)
    img = base * (0.8 + 0.2 * np.linspace(0, 1, h, dtype=np.float32))[:, None, None]
    img = img + 0.35 * np.clip(clouds - 0.5, 0, 1)[..., None]
    return Texture(np.clip(img, 0.02, 0.98).astype(np.float32), 2 * np.pi * SKY_RADIUS_M / w)


def _object_texture(rng: np.random.Generator, low_contrast: bool, floor_color) -> Texture:
    """Patterned object colours; low_contrast: close to the floor's colour and nearly plain, so
    RGB barely sees the object (only thermal does)."""
    if low_contrast:
        return plain_texture(rng, np.clip(np.asarray(floor_color) * rng.uniform(0.9, 1.1, 3), 0.02, 0.9),
                             contrast=0.08, texel_m=0.003)
    base = rng.uniform(0.05, 0.85, 3)
    accent = rng.uniform(0.05, 0.95, 3)
    return patterned_texture(rng, base=tuple(base), accent=tuple(accent), size_px=(256, 256),
                             texel_m=0.0005, marks=120)


# ------------------------------------------------------------------------------ motion
def _smooth(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3 - 2 * x)


@dataclass(frozen=True)
class Motion:
    """A path on (or above) the floor plus a spin, as functions of s = t / duration in [0, 1].

    kind: 'arc' (a half circle about `center`), 'line' (start -> end; may enter or leave the
    view), 'sweep' (back and forth between start and end) or 'static'. speed scales how far
    along its path the object is at s (a faster object covers the path, then stops)."""

    kind: str
    start: tuple[float, float]
    end: tuple[float, float]
    center: tuple[float, float] = (0.0, 0.0)
    arc_deg: float = 180.0
    height: float = 0.0            # extra lift above resting on the floor
    spin_deg: float = 0.0          # yaw turned over the path
    tilt_deg: float = 0.0          # a constant tilt of the spin axis
    speed: float = 1.0

    def progress(self, s: float) -> float:
        return min(s * self.speed, 1.0)

    def xy(self, s: float) -> np.ndarray:
        a = self.progress(s)
        if self.kind == "static":
            return np.asarray(self.start, float)
        if self.kind == "arc":
            c = np.asarray(self.center, float)
            r0 = np.asarray(self.start, float) - c
            ang = np.radians(self.arc_deg) * a
            rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
            return c + rot @ r0
        if self.kind == "sweep":
            a = 0.5 - 0.5 * np.cos(2 * np.pi * a)
        p0, p1 = np.asarray(self.start, float), np.asarray(self.end, float)
        return p0 + (p1 - p0) * a

    def rotation(self, s: float) -> np.ndarray:
        yaw = np.radians(self.spin_deg) * self.progress(s)
        return rotation("z", yaw) @ rotation("x", np.radians(self.tilt_deg))


@dataclass(frozen=True)
class Heat:
    """Surface temperature law: from k0 to k1 with time constant tau (s), plus a gradient of
    `gradient_k` along the object's local z and a hot spot of `spot_k` on one side."""

    k0: float
    k1: float
    tau: float
    gradient_k: float = 0.0
    spot_k: float = 0.0

    def mean_k(self, t: float) -> float:
        return self.k1 + (self.k0 - self.k1) * np.exp(-t / max(self.tau, 1e-3))

    def surface(self, t: float, p: np.ndarray, size: float) -> np.ndarray:
        """Kelvin (N,) at local points p (N, 3) of an object of characteristic size `size`."""
        k = self.mean_k(t) + self.gradient_k * p[:, 2] / size
        if self.spot_k:
            d2 = ((p[:, 0] - 0.7 * size) ** 2 + p[:, 1] ** 2) / (0.6 * size) ** 2
            k = k + self.spot_k * np.exp(-d2)
        return k.astype(np.float32)


@dataclass(frozen=True)
class SceneObject:
    name: str
    label: int
    shape: object                  # Sphere | Box | Cylinder (local frame as in shapes.py)
    rest_z: float                  # local origin height when resting on the floor
    texture: Texture
    motion: Motion
    heat: Heat
    size: float

    @property
    def moving(self) -> bool:
        return self.motion.kind != "static"

    def instance(self, t: float, duration: float) -> Instance:
        s = t / duration
        xy = self.motion.xy(s)
        pos = np.array([xy[0], xy[1], self.rest_z + self.motion.height])
        shape, tex, heat, size = self.shape, self.texture, self.heat, self.size
        return Instance(self.name, shape, self.motion.rotation(s), pos,
                        lambda p, n: tex.sample(shape.uv(p, n)),
                        lambda p: heat.surface(t, p, size), label=self.label)


# ------------------------------------------------------------------------------ the scene
@dataclass
class FamilyScene:
    """One scene of the family; `instances(t)` for t in [0, duration_s]. Build with `build`."""

    case: str
    seed: int
    settings: VariantSettings
    ambient_k: float
    floor: Texture
    floor_heat: Texture
    walls: list[tuple[Box, np.ndarray, np.ndarray, Texture]]
    sky: Texture
    sky_k: float
    objects: list[SceneObject]
    warm_spot: tuple[float, float, float, float, float]   # x, y, radius, kelvin above ambient, decay s
    paths: list[HandheldPath] = field(default_factory=list)
    rig_config: RigConfig | None = None
    duration_s: float = FAMILY_DURATION_S
    max_point_depth_m: float = 10.0   # SfM-like points: nothing on the sky

    @classmethod
    def build(cls, case: str, seed: int) -> "FamilyScene":
        if case not in CASES:
            raise ValueError(f"unknown family case {case!r}; choose one of {', '.join(CASES)}")
        rng = np.random.default_rng([seed, 0xFA111])
        ambient = C0 + rng.uniform(18, 26)
        light = rng.uniform(0.7, 1.2) if case != "dark" else rng.uniform(0.12, 0.25)
        settings = VariantSettings(light=light, gain=1.0 if case != "dark" else rng.uniform(2.0, 4.0))
        if rng.random() < 0.6:
            floor = checker_texture(rng, square_m=rng.uniform(0.05, 0.15))
        else:
            floor = plain_texture(rng, tuple(rng.uniform(0.2, 0.7, 3)), contrast=0.4, texel_m=0.004)
        floor_color = floor.image.reshape(-1, 3).mean(0)
        floor_heat = Texture(fbm(128, 128, rng, cell_px=20, octaves=3)[..., None] * 2 - 1, 0.02)
        paths = rig_paths(case, rng, FAMILY_DURATION_S)
        walls = cls._walls(rng, np.radians(paths[0].azimuth_deg) + np.pi)
        speed = 2.5 if case == "fast" else 1.0
        objects = cls._moving_objects(rng, ambient, speed, floor_color) + cls._static_objects(rng, ambient)
        objects = [replace(o, label=i + 1) for i, o in enumerate(objects)]
        spot = (rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(0.06, 0.15),
                rng.uniform(6, 20), rng.uniform(3, 30))
        scene = cls(case, seed, settings, ambient, floor, floor_heat, walls, sky_texture(rng),
                    C0 + rng.uniform(-25, -5), objects, spot)
        scene.paths = paths
        rgb_fov, th_fov = rng.uniform(45, 65), rng.uniform(24, 34)
        scene.rig_config = RigConfig(rgb=Intrinsics.from_fov(*REFERENCE_SIZE, hfov_deg=rgb_fov),
                                     thermal=Intrinsics.from_fov(*REFERENCE_SIZE, hfov_deg=th_fov,
                                                                 vfov_deg=0.75 * th_fov))
        return scene

    # ------------------------------------------------------------------ building blocks
    @staticmethod
    def _walls(rng: np.random.Generator, facing_az: float) -> list:
        """One to three wall panels 2.5-5 m from the centre around azimuth facing_az (radians,
        the side the training rig looks towards), facing the centre."""
        out = []
        for k in range(int(rng.integers(1, 4))):
            az = facing_az + rng.uniform(-1.2, 1.2)
            dist, width, height = rng.uniform(2.5, 5.0), rng.uniform(3.0, 6.0), rng.uniform(1.0, 2.5)
            box = Box((width / 2, 0.02, height / 2))
            pos = np.array([dist * np.sin(az), -dist * np.cos(az), height / 2])
            rot = rotation("z", az)
            color = tuple(rng.uniform(0.3, 0.85, 3))
            tex = plain_texture(rng, color, contrast=0.35, texel_m=0.01) if rng.random() < 0.5 else \
                patterned_texture(rng, base=color, accent=tuple(rng.uniform(0.05, 0.9, 3)),
                                  size_px=(256, 256), texel_m=0.006, marks=150)
            out.append((box, rot, pos, tex))
        return out

    @staticmethod
    def _moving_objects(rng, ambient: float, speed: float, floor_color) -> list[SceneObject]:
        out = []
        count = int(rng.integers(1, 4))
        kinds = rng.permutation(["ball", "box", "can"])
        for i in range(count):
            kind = kinds[i % 3]
            size = rng.uniform(0.04, 0.09)
            if kind == "ball":
                shape, rest_z = Sphere(size), size
            elif kind == "box":
                half = tuple(size * rng.uniform(0.6, 1.2, 3))
                shape, rest_z = Box(half), half[2]
            else:
                h = size * rng.uniform(1.2, 2.5)
                shape, rest_z = Cylinder(size * 0.7, h), 0.0
            hot = rng.random() < 0.8
            k0 = ambient + (rng.uniform(20, 90) if hot else -rng.uniform(12, 20))
            k1 = k0 + rng.uniform(-25, 25) if hot else k0 + rng.uniform(0, 5)
            heat = Heat(k0, max(k1, ambient + 5) if hot else k1, rng.uniform(2, 20),
                        gradient_k=rng.uniform(-4, 4), spot_k=rng.uniform(0, 10) if hot else 0.0)
            path_kind = rng.choice(["arc", "line", "sweep"], p=[0.45, 0.3, 0.25])
            spin = rng.uniform(-270, 270) if kind != "ball" or rng.random() < 0.5 else 0.0
            tilt = rng.uniform(-20, 20) if kind == "box" and rng.random() < 0.3 else 0.0
            if path_kind == "arc":
                c = rng.uniform(-0.15, 0.15, 2)
                r = rng.uniform(0.2, 0.45)
                a0 = rng.uniform(0, 2 * np.pi)
                motion = Motion("arc", tuple(c + r * np.array([np.cos(a0), np.sin(a0)])), (0, 0),
                                center=tuple(c), arc_deg=rng.choice([-1, 1]) * rng.uniform(150, 200),
                                spin_deg=spin, tilt_deg=tilt, speed=speed)
            elif path_kind == "line":
                d = rng.uniform(0, 2 * np.pi)
                # one in three lines enters or leaves the view (starts/ends ~1.5 m out)
                far = rng.random() < 0.33
                length = rng.uniform(1.2, 1.8) if far else rng.uniform(0.4, 0.8)
                mid = rng.uniform(-0.2, 0.2, 2)
                off = 0.5 * length * np.array([np.cos(d), np.sin(d)])
                start, end = (mid - off, mid + off) if not far else (mid, mid + 2 * off)
                if far and rng.random() < 0.5:
                    start, end = end, start
                motion = Motion("line", tuple(start), tuple(end), spin_deg=spin, tilt_deg=tilt,
                                speed=speed)
            else:
                d = rng.uniform(0, 2 * np.pi)
                length = rng.uniform(0.3, 0.6)
                mid = rng.uniform(-0.2, 0.2, 2)
                off = 0.5 * length * np.array([np.cos(d), np.sin(d)])
                motion = Motion("sweep", tuple(mid - off), tuple(mid + off), spin_deg=spin,
                                tilt_deg=tilt, speed=speed)
            if rng.random() < 0.2:
                motion = Motion(**{**motion.__dict__, "height": rng.uniform(0.05, 0.25)})
            low_contrast = rng.random() < 0.25
            out.append(SceneObject(f"moving {kind} {i}", 0, shape, rest_z,
                                   _object_texture(rng, low_contrast, floor_color), motion, heat, size))
        return out

    @staticmethod
    def _static_objects(rng, ambient: float) -> list[SceneObject]:
        out = []
        # a cup of hot liquid, cooling
        r, h = rng.uniform(0.04, 0.06), rng.uniform(0.09, 0.14)
        xy = rng.uniform(-0.4, 0.4, 2)
        cup = Cylinder(r, h)
        liquid0 = ambient + rng.uniform(35, 70)
        heat = Heat(liquid0, ambient + 10, rng.uniform(20, 60), gradient_k=rng.uniform(3, 10))
        out.append(SceneObject("cup", 0, cup, 0.0, _object_texture(rng, False, (0.5, 0.5, 0.5)),
                               Motion("static", tuple(xy), tuple(xy)), heat, h))
        if rng.random() < 0.7:   # a prop at room temperature
            half = tuple(rng.uniform(0.05, 0.12, 3))
            xy = rng.uniform(-0.5, 0.5, 2)
            out.append(SceneObject("prop", 0, Box(half), half[2], _object_texture(rng, False, (0.5, 0.5, 0.5)),
                                   Motion("static", tuple(xy), tuple(xy), spin_deg=0.0), Heat(ambient, ambient, 1.0),
                                   half[2]))
        return out

    # ------------------------------------------------------------------ the scene at t
    def mask_labels(self) -> dict[int, dict]:
        return {o.label: {"name": o.name, "moving": o.moving} for o in self.objects}

    def instances(self, t: float) -> list[Instance]:
        floor_half = (20.0, 20.0, 0.01)
        floor, heat, amb = self.floor, self.floor_heat, self.ambient_k
        x, y, radius, dk, decay = self.warm_spot

        def floor_temperature(p):
            k = amb - 0.5 + 0.4 * heat.sample(p[:, :2])[:, 0]
            spot = dk * np.exp(-t / decay) * np.exp(-((p[:, 0] - x) ** 2 + (p[:, 1] - y) ** 2) / radius ** 2)
            return (k + spot).astype(np.float32)

        out = [Instance("sky", Sphere(SKY_RADIUS_M), np.eye(3), np.zeros(3),
                        lambda p, n: self.sky.sample(_sky_uv(p)),
                        lambda p: np.full(len(p), self.sky_k, np.float32), emissive=True),
               Instance("floor", Box(floor_half), np.eye(3), np.array([0, 0, -floor_half[2]]),
                        lambda p, n: floor.sample(p[:, :2] + 3.0), floor_temperature)]
        for k, (box, rot, pos, tex) in enumerate(self.walls):
            out.append(Instance(f"wall {k}", box, rot, pos, lambda p, n, tex=tex, box=box: tex.sample(box.uv(p, n)),
                                lambda p: np.full(len(p), amb + 0.5, np.float32)))
        out += [o.instance(t, self.duration_s) for o in self.objects]
        return out


def _sky_uv(p: np.ndarray) -> np.ndarray:
    az = np.arctan2(p[:, 1], p[:, 0])
    el = np.arcsin(np.clip(p[:, 2] / SKY_RADIUS_M, -1, 1))
    return np.stack([az * SKY_RADIUS_M, el * SKY_RADIUS_M], axis=1)


# ------------------------------------------------------------------------------ the rigs
def rig_paths(case: str, rng: np.random.Generator, duration: float) -> list[HandheldPath]:
    """[training rig, held-out rig]. The training rig sweeps +-sweep degrees about a random
    azimuth; the held-out rig sweeps a narrow arc inside that range (inside, fast, dark) or
    17-45 degrees beyond its edge (outside), at a similar elevation and distance."""
    az0 = rng.uniform(0, 360)
    sweep = rng.uniform(30, 50)
    el = rng.uniform(10, 35)   # low rigs see walls and sky above them
    radius = rng.uniform(1.2, 2.0)
    target = (*rng.uniform(-0.1, 0.1, 2), 0.05)
    shake_freqs = lambda: rng.uniform(0.3, 1.8, size=(3, 3))   # noqa: E731
    shake_phases = lambda: rng.uniform(0, 2 * np.pi, size=(3, 3))   # noqa: E731
    train = HandheldPath(az0, sweep, el, rng.uniform(4, 10), radius, 1.0,
                         duration * rng.uniform(0.8, 1.2), 0.005, shake_freqs(), shake_phases(), target)
    side = rng.choice([-1.0, 1.0])
    if case == "outside":
        beyond = rng.uniform(17, 45)            # centre of the held-out arc beyond the edge
        own = min(beyond - 17, 45 - beyond, 8.0)
        az1, sweep1 = az0 + side * (sweep + beyond), own
    else:
        own = rng.uniform(4, 10)
        az1, sweep1 = az0 + side * rng.uniform(0, sweep - own - 5), own
    test = HandheldPath(az1, sweep1, el + rng.uniform(-4, 4), rng.uniform(1, 4),
                        radius * rng.uniform(0.9, 1.1), -1.0, duration * rng.uniform(0.8, 1.2), 0.005,
                        shake_freqs(), shake_phases(), target)
    return [train, test]


def case_of(variant: str) -> str | None:
    """'family-outside' -> 'outside'; None for a variant outside the family."""
    return variant[len(VARIANT_PREFIX):] if variant.startswith(VARIANT_PREFIX) else None
