"""The seeded scene family (rig/sim/family.py): new scenes per seed, rigs placed by the case."""
import numpy as np
import pytest

from rig.sim import FAMILY_VARIANTS, make_world
from rig.sim.family import CASES, FamilyScene


def azimuth_deg(world, rig: int, t: float) -> float:
    """Azimuth of a rig's RGB camera about its target, in the convention of HandheldPath."""
    eye = world.rig_pose(rig, t)[0][:3, 3] - np.asarray(world.paths[rig].target)
    return float(np.degrees(np.arctan2(eye[0], -eye[1])))


def sweep_deg(world, rig: int) -> tuple[float, float]:
    """(min, max) azimuth a rig visits, unwrapped around its sweep centre."""
    centre = world.paths[rig].azimuth_deg
    az = [(azimuth_deg(world, rig, t) - centre + 180) % 360 - 180 + centre
          for t in np.linspace(0, world.duration_s, 81)]
    return min(az), max(az)


def test_each_seed_is_a_new_scene_and_a_seed_is_always_the_same_scene():
    a, b, a2 = (FamilyScene.build("inside", s) for s in (1, 2, 1))
    assert [o.name for o in a.objects] == [o.name for o in a2.objects]
    assert a.ambient_k == a2.ambient_k
    assert (a.ambient_k, len(a.objects), a.paths[0].azimuth_deg) != (b.ambient_k, len(b.objects), b.paths[0].azimuth_deg)


@pytest.mark.parametrize("seed", range(6))
def test_held_out_rig_inside_or_beyond_the_training_sweep(seed):
    inside, outside = make_world("family-inside", seed), make_world("family-outside", seed)
    lo, hi = sweep_deg(inside, 0)
    lo1, hi1 = sweep_deg(inside, 1)
    assert lo - 1 <= lo1 and hi1 <= hi + 1, (lo, hi, lo1, hi1)
    lo, hi = sweep_deg(outside, 0)
    lo1, hi1 = sweep_deg(outside, 1)
    beyond = max(lo1 - hi, lo - hi1)          # the gap between the two arcs, degrees
    assert 12 <= beyond and max(hi1 - hi, lo - lo1) <= 50, (lo, hi, lo1, hi1)


def test_objects_are_labelled_and_moving_ones_move():
    scene = FamilyScene.build("outside", 3)
    labels = scene.mask_labels()
    assert sorted(labels) == list(range(1, len(scene.objects) + 1))
    moving = [o for o in scene.objects if labels[o.label]["moving"]]
    assert moving and any(not v["moving"] for v in labels.values())     # the cup stays
    for o in moving:
        start, end = (o.instance(t, scene.duration_s).position for t in (0.0, scene.duration_s))
        assert np.linalg.norm(end - start) > 0.05 or o.motion.kind == "sweep"
    by_name = {i.name: i for i in scene.instances(1.0)}
    assert by_name["sky"].emissive and by_name["floor"].label == 0


def test_fast_case_moves_objects_further_and_dark_case_has_less_light():
    base, fast, dark = (FamilyScene.build(c, 5) for c in ("inside", "fast", "dark"))
    assert all(f.motion.speed == 2.5 for f in fast.objects if f.moving)
    assert dark.settings.light < 0.3 <= base.settings.light


def test_sparse_points_have_nothing_on_the_sky():
    world = make_world("family-inside", 0)
    xyz, rgb = world.visible_points([0.0, 4.0], per_view=400, rng=np.random.default_rng(0))
    assert len(xyz) > 300 and np.linalg.norm(xyz, axis=1).max() < 12.0


def test_every_case_renders_both_modalities():
    assert FAMILY_VARIANTS == tuple(f"family-{c}" for c in CASES)
    world = make_world("family-dark", 2)
    k = world.rig_config.thermal.scaled(40, 30)
    c2w_rgb, c2w_th = world.rig_pose(1, 2.0)
    kelvin = world.render_temperature(c2w_th, k.fx, k.fy, k.cx, k.cy, k.width, k.height, 2.0)
    kr = world.rig_config.rgb.scaled(40, 30)
    rgb = world.render_rgb(c2w_rgb, kr.fx, kr.fy, kr.cx, kr.cy, kr.width, kr.height, 2.0)
    lo, hi = world.temperature_range_k
    assert kelvin.shape == (30, 40) and lo <= kelvin.min() and kelvin.max() <= hi
    assert rgb.shape == (30, 40, 3) and rgb.dtype == np.uint8
