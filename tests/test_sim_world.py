"""The simulated world: geometry conventions, temperature laws, variants, determinism."""
import numpy as np
import pytest

from rig.sim import VARIANTS, make_world
from rig.sim.tabletop import C0, PLATE_H, PLATE_XY

SIZE = (96, 72)


@pytest.fixture(scope="module")
def world():
    return make_world("default", seed=3)


def _frame(world, rig, t, modality, size=SIZE, rng=None):
    c2w_rgb, c2w_th = world.rig_pose(rig, t)
    cfg = world.rig_config
    if modality == "rgb":
        k = cfg.rgb.scaled(*size)
        return world.render_rgb(c2w_rgb, k.fx, k.fy, k.cx, k.cy, k.width, k.height, t, rng=rng)
    k = cfg.thermal.scaled(*size)
    return world.render_temperature(c2w_th, k.fx, k.fy, k.cx, k.cy, k.width, k.height, t)


def _project(c2w, k, point):
    """Pixel (col, row) containing a world point under the documented pinhole convention."""
    x, y, z = np.linalg.inv(c2w)[:3] @ np.append(point, 1.0)
    return int(np.floor(k.fx * x / z + k.cx)), int(np.floor(k.fy * y / z + k.cy))


def test_poses_are_rigid_and_rigs_see_from_different_sides(world):
    for rig in (0, 1):
        for t in (0.0, 2.5, 7.0):
            for c2w in world.rig_pose(rig, t):
                r = c2w[:3, :3]
                np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)
                assert np.linalg.det(r) == pytest.approx(1.0)
                assert c2w[2, 3] > 0.2  # above the table
                assert c2w[:3, 2] @ (np.zeros(3) - c2w[:3, 3]) > 0  # facing the scene
    rgb0, th0 = world.rig_pose(0, 2.5)
    rgb1, _ = world.rig_pose(1, 2.5)
    baseline = np.linalg.norm(th0[:3, 3] - rgb0[:3, 3])
    assert 0.02 < baseline < 0.08
    az0 = np.arctan2(rgb0[0, 3], -rgb0[1, 3])
    az1 = np.arctan2(rgb1[0, 3], -rgb1[1, 3])
    assert np.sign(az0) != np.sign(az1) and abs(np.degrees(az0 - az1)) > 30


def test_hot_plate_centre_has_the_scripted_temperature_at_its_projected_pixel(world):
    """Checks projection convention, pose, ray caster and the heating law together."""
    t = 6.0
    _, c2w = world.rig_pose(0, t)
    k = world.rig_config.thermal.scaled(320, 240)
    kelvin = world.render_temperature(c2w, k.fx, k.fy, k.cx, k.cy, k.width, k.height, t)
    col, row = _project(c2w, k, np.array([*PLATE_XY, PLATE_H]))
    expected = world.scene.plate_k(t)
    assert kelvin[row, col] == pytest.approx(expected, abs=0.3)
    assert world.scene.plate_k(6.0) - world.scene.plate_k(0.0) > 50  # it heats fast


def test_depth_of_the_table_top_matches_a_plane_intersection(world):
    c2w, _ = world.rig_pose(0, 1.0)
    k = world.rig_config.rgb.scaled(*SIZE)
    depth = world.render_depth(c2w, k.fx, k.fy, k.cx, k.cy, k.width, k.height, 1.0)
    row, col = SIZE[1] - 3, 4  # bottom-left: bare table
    d_cam = np.array([(col + 0.5 - k.cx) / k.fx, (row + 0.5 - k.cy) / k.fy, 1.0])
    d_world = c2w[:3, :3] @ d_cam
    expected = -c2w[2, 3] / d_world[2]  # plane z = 0
    assert depth[row, col] == pytest.approx(expected, rel=1e-4)


def test_temperature_edges_are_anti_aliased(world):
    kelvin = _frame(world, 0, 8.0, "thermal", size=(160, 120))
    plate, table = world.scene.plate_k(8.0), kelvin.min()
    between = (kelvin > 320) & (kelvin < 340)  # neither table (~295-310) nor plate (~380)
    assert plate > 370 and table < 300
    assert between.sum() > 10


def test_temperatures_span_the_table_top_range(world):
    lo, hi = world.temperature_range_k
    assert C0 + 3 < lo < C0 + 12 and C0 + 110 < hi < C0 + 125
    kelvin = _frame(world, 0, 9.0, "thermal")
    assert lo <= kelvin.min() and kelvin.max() <= hi


def test_same_seed_same_frames_and_other_seed_other_frames():
    a, b, c = make_world("default", 7), make_world("default", 7), make_world("default", 8)
    frames = [_frame(w, 1, 4.2, "rgb", rng=np.random.default_rng(5)) for w in (a, b, c)]
    np.testing.assert_array_equal(frames[0], frames[1])
    assert np.abs(frames[0].astype(int) - frames[2]).mean() > 5
    np.testing.assert_array_equal(_frame(a, 0, 3.3, "thermal"), _frame(b, 0, 3.3, "thermal"))


def test_time_past_the_script_is_reflected(world):
    d = world.duration_s
    np.testing.assert_array_equal(_frame(world, 0, d + 1.5, "thermal"),
                                  _frame(world, 0, d - 1.5, "thermal"))
    np.testing.assert_allclose(world.rig_pose(1, 2 * d + 0.5)[0], world.rig_pose(1, 0.5)[0])


def test_rgb_noise_only_with_rng(world):
    clean = _frame(world, 0, 1.0, "rgb").astype(float)
    noisy = _frame(world, 0, 1.0, "rgb", rng=np.random.default_rng(0)).astype(float)
    np.testing.assert_array_equal(clean, _frame(world, 0, 1.0, "rgb"))
    assert 0.5 < np.abs(noisy - clean).mean() < 6


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_renders(variant):
    w = make_world(variant, 0)
    rgb = _frame(w, 1, 5.0, "rgb", size=(32, 24), rng=np.random.default_rng(0))
    kelvin = _frame(w, 1, 5.0, "thermal", size=(32, 24))
    assert rgb.shape == (24, 32, 3) and rgb.dtype == np.uint8
    assert kelvin.shape == (24, 32) and np.isfinite(kelvin).all()


def test_variants_stress_what_they_say():
    worlds = {v: make_world(v, 0) for v in VARIANTS}
    base = worlds["default"]
    # dark: much darker and noisier RGB
    dark = _frame(worlds["dark"], 0, 1.0, "rgb", rng=np.random.default_rng(0)).astype(float)
    bright = _frame(base, 0, 1.0, "rgb", rng=np.random.default_rng(0)).astype(float)
    assert dark.mean() < 0.75 * bright.mean()
    # fast: the camera moves more in a tenth of a second
    step = {v: np.linalg.norm(worlds[v].rig_pose(0, 2.1)[0][:3, 3] - worlds[v].rig_pose(0, 2.0)[0][:3, 3])
            for v in ("default", "fast")}
    assert step["fast"] > 2.5 * step["default"]
    # occlusion: an arm crosses the views mid-sequence only
    names = lambda w, t: {i.name for i in w.scene.instances(t)}
    assert "arm" in names(worlds["occlusion"], 5.0) and "arm" not in names(worlds["occlusion"], 1.0)
    assert "arm" not in names(base, 5.0)
    # flat-thermal: near-uniform temperatures
    assert _frame(worlds["flat-thermal"], 0, 8.0, "thermal").std() < 0.05 * _frame(base, 0, 8.0, "thermal").std()
    # rapid: the heater jumps tens of kelvin within a quarter second
    rapid = worlds["rapid"].scene
    assert abs(rapid.plate_k(4.25) - rapid.plate_k(3.95)) > 30
    assert abs(base.scene.plate_k(4.25) - base.scene.plate_k(3.95)) < 5


def test_visible_points_lie_on_rendered_surfaces(world):
    xyz, rgb = world.visible_points([0.0, 5.0], per_view=200, rng=np.random.default_rng(0),
                                    noise_m=0.0)
    assert xyz.shape == (400, 3) and rgb.shape == (400, 3) and rgb.dtype == np.uint8
    c2w, _ = world.rig_pose(0, 0.0)
    k = world.rig_config.rgb.scaled(160, 120)
    depth = world.render_depth(c2w, k.fx, k.fy, k.cx, k.cy, k.width, k.height, 0.0)
    cam = (np.linalg.inv(c2w) @ np.c_[xyz[:200], np.ones(200)].T)[:3].T
    cols = np.floor(k.fx * cam[:, 0] / cam[:, 2] + k.cx).astype(int)
    rows = np.floor(k.fy * cam[:, 1] / cam[:, 2] + k.cy).astype(int)
    np.testing.assert_allclose(cam[:, 2], depth[rows, cols], rtol=1e-4)
