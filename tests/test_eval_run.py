"""`recon eval`: renders compared with a simulated dataset's ground truth."""
import json
import math
import shutil

import cv2
import numpy as np
import pytest

from recon.cli import main as recon_main
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.eval import RenderError, evaluate_run, write_render
from recon.eval.renders import render_path
from recon.viz import colorbar, colormap


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    simulate_dataset(out, SimulateConfig(frames=2, width=40, height=30, seed=2, points=100))
    return out


def _copy_gt(ds, run, offset_counts=0):
    for f in ds.split("rgb", "test") + ds.split("thermal", "test"):
        target = render_path(run, f)
        target.parent.mkdir(parents=True, exist_ok=True)
        if f.modality == "thermal" and offset_counts:
            write_render(run, f, (ds.read_raw(f).astype(np.float64) + offset_counts) * ds.thermal_scale_k,
                         ds.thermal_scale_k)
        else:
            shutil.copy(ds.path(f), target)


def test_ground_truth_as_render_is_perfect(dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("THERMAL4D_LPIPS_WEIGHTS", str(tmp_path / "absent.ckpt"))
    ds = load_dataset(dataset)
    _copy_gt(ds, tmp_path)
    result = evaluate_run(tmp_path, dataset)
    assert result["mean"]["rgb"]["frames"] == 2 and result["mean"]["thermal"]["frames"] == 2
    for modality in ("rgb", "thermal"):
        assert math.isinf(result["mean"][modality]["psnr"])
        assert result["mean"][modality]["ssim"] == pytest.approx(1.0, abs=1e-6)
        assert "lpips" not in result["mean"][modality]  # weights absent: omitted ...
    assert result["conventions"]["lpips"].startswith("omitted")  # ... and said so
    assert result["mean"]["thermal"]["mae_k"] == 0.0
    assert {r["camera"] for r in result["per_frame"]} == {"cam1"}


def test_one_kelvin_offset_and_cli_outputs(dataset, tmp_path):
    ds = load_dataset(dataset)
    _copy_gt(ds, tmp_path, offset_counts=round(1.0 / ds.thermal_scale_k))
    assert recon_main(["eval", str(tmp_path), str(dataset), "--no-lpips"]) == 0
    text = (tmp_path / "eval" / "metrics.json").read_text()
    result = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))
    thermal = result["mean"]["thermal"]
    assert thermal["mae_k"] == pytest.approx(1.0, abs=1e-3)
    span = ds.thermal_range_k[1] - ds.thermal_range_k[0]
    assert thermal["psnr"] == pytest.approx(20 * math.log10(span / 1.0), abs=0.05)
    assert result["mean"]["rgb"]["psnr"] == "inf"
    md = (tmp_path / "eval" / "metrics.md").read_text()
    assert "| thermal | 2 |" in md and "1.000" in md and "disabled" in md


def test_missing_and_mismatched_renders_are_named(dataset, tmp_path, capsys):
    ds = load_dataset(dataset)
    _copy_gt(ds, tmp_path)
    victim = ds.split("thermal", "test")[0]
    render_path(tmp_path, victim).unlink()
    with pytest.raises(RenderError, match=victim.file_path):
        evaluate_run(tmp_path, dataset)
    assert recon_main(["eval", str(tmp_path), str(dataset)]) == 2
    assert "renders missing" in capsys.readouterr().err
    cv2.imwrite(str(render_path(tmp_path, victim)), np.full((10, 10), 30000, np.uint16))
    with pytest.raises(RenderError, match="10x10"):
        evaluate_run(tmp_path, dataset)
    with pytest.raises(RenderError, match="10x10"):
        write_render(tmp_path, victim, np.full((10, 10), 300.0), ds.thermal_scale_k)


def test_cli_strips_are_gt_render_error_with_colourbars(dataset, tmp_path):
    """`recon eval --strips`: one picture per test frame; a thermal strip holds GT | render | °C
    bar | |error| | K bar, frames enlarged x8 (30 px -> 240 px), a +1.5 K right half shows in the
    error panel and sets the error bar's range."""
    ds = load_dataset(dataset)
    _copy_gt(ds, tmp_path)
    th = ds.split("thermal", "test")[0]
    counts = ds.read_raw(th).astype(np.float64)
    counts[:, 20:] += round(1.5 / ds.thermal_scale_k)
    write_render(tmp_path, th, counts * ds.thermal_scale_k, ds.thermal_scale_k)
    assert recon_main(["eval", str(tmp_path), str(dataset), "--no-lpips", "--strips"]) == 0
    strips = tmp_path / "eval" / "strips"
    test_frames = ds.split("rgb", "test") + ds.split("thermal", "test")
    assert sorted(p.relative_to(strips).as_posix() for p in strips.rglob("*.png")) == sorted(
        f.file_path for f in test_frames)

    picture = cv2.imread(str(strips / th.file_path))[..., ::-1]
    panel_h, panel_w, gap = 240, 320, 6
    band = picture.shape[0] - panel_h                             # title band above every panel
    c_bar = colorbar(panel_h, *ds.thermal_range_k)                 # °C bar of GT and render
    k_bar = colorbar(panel_h, 0, 1.5, "inferno", unit="K", offset=0.0)
    assert 10 < band < 60
    assert picture.shape[1] == 3 * panel_w + c_bar.shape[1] + k_bar.shape[1] + 4 * gap
    body = picture[band:]
    x_bar = 2 * (panel_w + gap)
    np.testing.assert_array_equal(body[:, x_bar:x_bar + c_bar.shape[1]], c_bar)
    np.testing.assert_array_equal(body[:, -k_bar.shape[1]:], k_bar)
    x_err = x_bar + c_bar.shape[1] + gap
    error = body[:, x_err:x_err + panel_w]
    valid = np.repeat(np.repeat(np.isfinite(ds.image(th)), 8, 0), 8, 1)
    inferno = colormap("inferno")
    left, right = error[:, :160][valid[:, :160]], error[:, 160:][valid[:, 160:]]
    assert left.size and right.size
    assert (left == inferno[0]).all() and (right == inferno[255]).all()

    rgb = cv2.imread(str(strips / ds.split("rgb", "test")[0].file_path))[..., ::-1]
    d_bar = colorbar(panel_h, 0, 0.25, "inferno", unit="|d|", offset=0.0)
    assert rgb.shape == (panel_h + band, 3 * panel_w + d_bar.shape[1] + 3 * gap, 3)


def test_a_single_modality_run_is_graded_on_its_own_modality(dataset, tmp_path, capsys):
    """A thermal-only method (its config.json says so) writes no RGB renders: `recon eval` grades
    the thermal frames instead of calling every RGB render missing; without a config, the
    renders/ folders present decide."""
    ds = load_dataset(dataset)
    _copy_gt(ds, tmp_path)
    shutil.rmtree(tmp_path / "renders" / "rgb")
    assert recon_main(["eval", str(tmp_path), str(dataset), "--no-lpips", "--strips"]) == 0
    result = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert list(result["mean"]) == ["thermal"] and result["mean"]["thermal"]["mae_k"] == 0.0
    assert not (tmp_path / "eval" / "strips" / "rgb").exists()
    (tmp_path / "config.json").write_text(json.dumps({"model": {"modalities": ["rgb", "thermal"]}}))
    assert recon_main(["eval", str(tmp_path), str(dataset), "--no-lpips"]) == 2      # the config asks for RGB
    assert "renders missing" in capsys.readouterr().err
