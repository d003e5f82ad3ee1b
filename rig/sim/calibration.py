"""A heated checkerboard calibration target seen by the simulated rig (for `rig calibrate`).

The board (9 x 7 squares of 1.6 cm, a 2 cm white margin, 6 mm thick) stands on a post at the
table-top scene's centre, facing the rigs' average viewpoint (35 degrees up, azimuth 0). Under a
heat lamp its black squares absorb more: in thermal they are warmer (45 C) than the white ones
(28 C), with edges softened by lateral conduction (1.5 mm). The rigs move as in the table-top
world, so a sequence gives the varied views a stereo calibration needs.

    world = make_calibration_world(seed=0)
    corners = world.scene.inner_corners_world()   # (48, 3) ground truth for detections
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from rig.sim.raycast import Instance
from rig.sim.rig_config import RigConfig
from rig.sim.shapes import Box
from rig.sim.tabletop import AMBIENT_K, ROOM_CENTER, ROOM_HALF, VariantSettings
from rig.sim.checkerboard import CheckerboardTarget
from rig.sim.textures import Texture, plain_texture
from rig.sim.trajectory import TARGET
from rig.sim.world import World

def _facing_rotation(elevation_deg: float = 35.0) -> np.ndarray:
    """Board frame -> world: x along world x, z (the face normal) towards the rigs."""
    el = np.radians(elevation_deg)
    z = np.array([0.0, -np.cos(el), np.sin(el)])
    x = np.array([1.0, 0.0, 0.0])
    return np.stack([x, np.cross(z, x), z], axis=1)


@dataclass
class CalibrationScene:
    """A static scene: the room and the heated checkerboard (duck-types TableTopScene)."""

    target: CheckerboardTarget
    room: Texture
    settings: VariantSettings = field(default_factory=VariantSettings)
    rotation: np.ndarray = field(default_factory=_facing_rotation)
    position: np.ndarray = field(default_factory=lambda: TARGET.copy())

    def inner_corners_world(self) -> np.ndarray:
        """(N, 3) world positions of the inner corners, in cv2 row-by-row order."""
        return self.target.inner_corners_local() @ self.rotation.T + self.position

    def instances(self, t: float) -> list[Instance]:
        target, half = self.target, (*(s / 2 for s in self.target.size_m), self.target.thickness_m / 2)
        albedo, kelvin = target.face_textures()
        room, board = Box(ROOM_HALF, inside=True), Box(half)
        grey = np.float32(0.3)

        def face_uv(p):
            return p[:, :2] + np.array(half[:2])

        def board_albedo(p, n):
            out = np.full((len(p), 3), grey, np.float32)
            front = n[:, 2] > 0.5
            out[front] = albedo.sample(face_uv(p[front]))
            return out

        def board_temperature(p):
            out = np.full(len(p), AMBIENT_K + 3.0, np.float32)
            front = p[:, 2] > half[2] - 1e-5
            out[front] = kelvin.sample(face_uv(p[front]))[:, 0]
            return out

        return [Instance("room", room, np.eye(3), ROOM_CENTER,
                         lambda p, n: self.room.sample(room.uv(p, n)),
                         lambda p: np.full(len(p), AMBIENT_K, np.float32)),
                Instance("checkerboard", board, self.rotation, self.position, board_albedo,
                         board_temperature)]


def make_calibration_world(seed: int = 0, target: CheckerboardTarget | None = None,
                           rig_config: RigConfig | None = None) -> World:
    """The rigs of the table-top world looking at a heated checkerboard instead of the table."""
    rng = np.random.default_rng([seed, 0xCA11B])
    scene = CalibrationScene(target or CheckerboardTarget(),
                             plain_texture(rng, (0.55, 0.52, 0.48), contrast=0.25))
    return World("default", seed, rig_config, scene=scene)


def write_view_pairs(world: World, folder, times, size: tuple[int, int] = (320, 240), rig: int = 0) -> None:
    """What `rig calibrate` takes as a folder: folder/rgb/NNN.png (8-bit sRGB, phone noise) and
    folder/thermal/NNN.png (TemperatureLinear10mK counts, NETD noise) of `rig` at `times` (s)."""
    from pathlib import Path
    folder = Path(folder)
    (folder / "rgb").mkdir(parents=True, exist_ok=True)
    (folder / "thermal").mkdir(exist_ok=True)
    rc = world.rig_config
    k, kt = rc.rgb.scaled(*size), rc.thermal.scaled(*size)
    for i, t in enumerate(times):
        c2w_rgb, c2w_th = world.rig_pose(rig, t)
        rng = np.random.default_rng([world.seed, i])
        rgb = world.render_rgb(c2w_rgb, k.fx, k.fy, k.cx, k.cy, *size, t, rng=rng)
        kelvin = world.render_temperature(c2w_th, kt.fx, kt.fy, kt.cx, kt.cy, *size, t)
        cv2.imwrite(str(folder / "rgb" / f"{i:03d}.png"), np.ascontiguousarray(rgb[..., ::-1]))
        cv2.imwrite(str(folder / "thermal" / f"{i:03d}.png"), world.thermal_counts(kelvin, rng))
