"""FLIR TemperatureLinear count encoding and NETD noise of the simulated thermal camera."""
import numpy as np

from rig.sim import make_world


def test_counts_encode_kelvin_in_scale_steps_with_netd_noise():
    world = make_world("default", 0)
    kelvin = np.full((200, 300), 310.123)
    counts = world.thermal_counts(kelvin, np.random.default_rng(1), scale_k=0.01)
    assert counts.dtype == np.uint16
    decoded = counts * 0.01
    assert abs(decoded.mean() - 310.123) < 0.002
    assert abs(decoded.std() - world.rig_config.netd_k) < 0.002  # 40 mK NETD, 60k samples
    assert world.rig_config.netd_k == 0.04


def test_noise_free_counts_round_to_the_nearest_step_and_support_0_1_k():
    world = make_world("default", 0)
    kelvin = np.array([[300.004, 300.006], [450.0, 273.17]])
    np.testing.assert_array_equal(world.thermal_counts(kelvin, None, 0.01),
                                  [[30000, 30001], [45000, 27317]])
    np.testing.assert_array_equal(world.thermal_counts(kelvin, None, 0.1),
                                  [[3000, 3000], [4500, 2732]])


def test_zero_is_reserved_for_no_measurement():
    world = make_world("default", 0)
    counts = world.thermal_counts(np.array([np.nan, 1e-6, 1e9]), np.random.default_rng(0))
    np.testing.assert_array_equal(counts, [0, 1, 65535])


def test_same_rng_seed_same_counts():
    world = make_world("default", 0)
    kelvin = np.linspace(280, 390, 50).reshape(5, 10)
    a = world.thermal_counts(kelvin, np.random.default_rng(4))
    b = world.thermal_counts(kelvin, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
