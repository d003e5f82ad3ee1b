"""Thermal colour maps, °C colourbars and GT / render / error strips."""
import cv2
import numpy as np
import pytest

from recon.viz import (C0, INVALID_RGB, colorbar, colorbar_ticks, colorize, colormap, rgb_strip,
                       save_png, thermal_image, thermal_strip)
from recon.viz import _nice_ticks


def _luma(rgb):
    return rgb.astype(float) @ [0.299, 0.587, 0.114]


@pytest.mark.parametrize("name", ["ironbow", "inferno"])
def test_colour_maps_run_dark_to_bright(name):
    lut = colormap(name)
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    luma = _luma(lut)
    assert luma[0] < 15 and luma[-1] > 200
    assert np.all(np.diff(luma) > -1.0)  # monotonic up to rounding: hotter is brighter


def test_inferno_is_opencvs():
    ref = cv2.applyColorMap(np.array([[0, 128, 255]], np.uint8), cv2.COLORMAP_INFERNO)[0, :, ::-1]
    np.testing.assert_array_equal(colormap("inferno")[[0, 128, 255]], ref)


def test_colorize_maps_range_ends_and_marks_missing():
    kelvin = np.array([[280.0, 330.0, np.nan, 500.0]])
    out = colorize(kelvin, 280.0, 330.0)
    lut = colormap("ironbow")
    np.testing.assert_array_equal(out[0, 0], lut[0])
    np.testing.assert_array_equal(out[0, 1], lut[255])
    np.testing.assert_array_equal(out[0, 2], INVALID_RGB)
    np.testing.assert_array_equal(out[0, 3], lut[255])  # clipped


def test_ticks_are_round_numbers_inside_the_range():
    np.testing.assert_allclose(_nice_ticks(6.0, 115.0), [20, 40, 60, 80, 100])
    ticks = _nice_ticks(21.3, 23.9)
    assert ticks[0] >= 21.3 and ticks[-1] <= 23.9 and len(ticks) >= 3
    np.testing.assert_allclose(np.diff(ticks), np.diff(ticks)[0])


def test_colorbar_has_a_ramp_and_labels():
    bar = colorbar(240, C0 + 10, C0 + 110)
    assert bar.shape[0] == 240 and 40 < bar.shape[1] < 120
    ramp_column = bar[30:230, 8]
    assert _luma(ramp_column[0:1])[0] > _luma(ramp_column[-1:])[0] + 150  # hot on top
    text_area = bar[:, 25:]
    assert (text_area < 100).any()  # black label pixels


def test_colorbar_ticks_are_kelvin_converted_to_celsius():
    ticks, labels = colorbar_ticks(C0 + 10, C0 + 110)          # 283.15 .. 383.15 K
    np.testing.assert_allclose(ticks, [20, 40, 60, 80, 100])
    assert labels == ["20", "40", "60", "80", "100"]
    ticks, labels = colorbar_ticks(294.0, 297.0)                # 20.85 .. 23.85 °C
    np.testing.assert_allclose(ticks, [21.0, 21.5, 22.0, 22.5, 23.0, 23.5])
    assert labels == ["21.0", "21.5", "22.0", "22.5", "23.0", "23.5"]
    _, kelvin_labels = colorbar_ticks(290.0, 350.0, offset=0.0)  # differences / K bars keep kelvin
    assert kelvin_labels == ["290", "300", "310", "320", "330", "340", "350"]


def _longest_run(mask):
    """(start, stop) of the longest run of True in a 1-D mask."""
    best, start = (0, 0), None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            best, start = max(best, (start, i), key=lambda r: r[1] - r[0]), None
    return best


def test_colorbar_tick_marks_sit_at_the_celsius_values():
    """The drawn tick marks are where 20, 40 ... 100 °C fall on a 10..110 °C ramp (in kelvin
    they would be 300, 320 ... K: each mark ~14 px higher)."""
    bar = colorbar(240, C0 + 10, C0 + 110)
    top, bottom = _longest_run((bar[:, 8] != 255).any(axis=1))  # the colour ramp's rows
    marks = [y for y in range(top, bottom + 1) if (bar[y, 19] < 60).all()]  # tick marks, right of the ramp
    ticks, _ = colorbar_ticks(C0 + 10, C0 + 110)
    expected = [int(round(bottom - (t - 10) / 100 * (bottom - top))) for t in ticks]
    assert marks == [y for y in sorted(expected) if y <= bottom]


def test_thermal_strip_panels_and_zero_error():
    gt = np.linspace(290, 350, 40 * 30).reshape(30, 40)
    strip = thermal_strip(gt, gt.copy(), 290.0, 350.0, min_height=60)
    assert strip.dtype == np.uint8 and strip.shape[1] > 3 * 80
    # error panel of identical frames: every pixel is the colour of 0 K
    zero = colormap("inferno")[0]
    title_h = strip.shape[0] - 60
    err_cols = [c for c in range(strip.shape[1]) if (strip[title_h:, c] == zero).all()]
    assert len(err_cols) >= 80
    gt_panel = strip[title_h:, :80]
    expected = np.repeat(np.repeat(colorize(gt, 290.0, 350.0), 2, 0), 2, 1)
    np.testing.assert_array_equal(gt_panel, expected)


def test_strip_rejects_mismatched_frames():
    with pytest.raises(ValueError, match="differ"):
        thermal_strip(np.zeros((4, 5)), np.zeros((5, 4)))


def test_thermal_image_and_rgb_strip_save(tmp_path):
    kelvin = 300 + np.random.default_rng(0).random((24, 32)) * 20
    img = thermal_image(kelvin, title="test")
    assert img.shape[0] >= 240
    rgb = (np.random.default_rng(1).random((24, 32, 3)) * 255).astype(np.uint8)
    strip = rgb_strip(rgb, rgb)
    path = save_png(tmp_path / "a" / "strip.png", strip)
    np.testing.assert_array_equal(cv2.imread(str(path))[..., ::-1], strip)
