"""Simulated dynamic RGB-thermal world with its own analytic ray caster.

Used by the rig's simulated capture, the GigE camera fake, `recon simulate`, the demo and the
benchmarks. It never imports `recon` (so reconstruction is never graded by code it tests).

    from rig.sim import make_world, VARIANTS
    world = make_world("default", seed=0)
    c2w_rgb, c2w_thermal = world.rig_pose(0, 1.5)
    k = world.rig_config.thermal.scaled(160, 120)
    kelvin = world.render_temperature(c2w_thermal, k.fx, k.fy, k.cx, k.cy, k.width, k.height, 1.5)

`make_world("family-outside", seed)` is one scene of the seeded family (rig/sim/family.py).
`make_calibration_world()` puts a heated checkerboard in front of the same rigs (rig calibrate).
"""
from rig.sim.calibration import CheckerboardTarget, make_calibration_world
from rig.sim.camera import Intrinsics
from rig.sim.rig_config import RigConfig
from rig.sim.family import FAMILY_VARIANTS
from rig.sim.tabletop import VARIANTS
from rig.sim.world import World, make_world

__all__ = ["CheckerboardTarget", "FAMILY_VARIANTS", "Intrinsics", "RigConfig", "VARIANTS", "World",
           "make_calibration_world", "make_world"]
