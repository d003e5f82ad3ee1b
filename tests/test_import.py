"""Recordings made with other tools: an RGBT-Scenes folder (rgb/ + thermal/ + a COLMAP sparse model)
through `recon prepare` into a dataset that `recon run` trains on; a plain folder of radiometric
16-bit frames with a timestamps CSV plus the phone video through `rig import thermal` into a session
that `recon prepare` and `recon run` take; malformed inputs end in one line naming the file."""
import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from recon.cli import main as recon_main
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.prepare.poses import pose_errors, quat_from_matrix
from recon.prepare.simtruth import session_truth
from rig.calibrate import Lens, RigCalibration, simulated_calibration
from rig.capture.config import CaptureConfig
from rig.capture.session_capture import Capture
from rig.cli import main as rig_main
from rig.session import open_session

RUN = ["--iterations", "20", "--threads", "1"]
PSNR_FLOOR_DB = {"rgb": 12.0, "thermal": 12.0}   # measured 17.4-18.1 / 15.6-17.5 dB at 20 iterations (docs/import.md)


def _one_line_naming(err: str, name: str) -> None:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and name in lines[0], err


# -- an RGBT-Scenes folder from the simulator's ground truth ------------------------------------------

def _write_model(folder: Path, views: list[tuple[str, object]], xyz: np.ndarray, rgb: np.ndarray) -> None:
    """COLMAP text model: one PINHOLE camera per (size, intrinsics), each view's world-to-camera."""
    folder.mkdir(parents=True)
    cams, cam_lines, img_lines = {}, [], []
    for i, (name, fr) in enumerate(views, 1):
        key = (fr.width, fr.height, fr.fx, fr.fy, fr.cx, fr.cy)
        if key not in cams:
            cams[key] = len(cams) + 1
            cam_lines.append(f"{cams[key]} PINHOLE {fr.width} {fr.height} {fr.fx!r} {fr.fy!r} {fr.cx!r} {fr.cy!r}")
        w2c = np.linalg.inv(fr.c2w_opencv())
        q, t = quat_from_matrix(w2c[:3, :3]), w2c[:3, 3]
        img_lines += [f"{i} {' '.join(repr(float(v)) for v in (*q, *t))} {cams[key]} {name}", ""]
    (folder / "cameras.txt").write_text("# Camera list\n" + "\n".join(cam_lines) + "\n")
    (folder / "images.txt").write_text("# Image list\n" + "\n".join(img_lines) + "\n")
    (folder / "points3D.txt").write_text("".join(
        f"{i} {x!r} {y!r} {z!r} {r} {g} {b} 0.5\n"
        for i, ((x, y, z), (r, g, b)) in enumerate(zip(xyz.tolist(), rgb.tolist()), 1)))


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "data"
    simulate_dataset(out, SimulateConfig(frames=12, width=160, height=120, rigs=1, points=1500))
    return out


def _rgbt_folder(sim: Path, dest: Path, register_thermal: bool, thermal_8bit: bool = False) -> Path:
    """The RGBT-Scenes layout: rgb/NAME.png, thermal/NAME.png (same stem), sparse/0/*.txt."""
    ds = load_dataset(sim)
    (dest / "rgb").mkdir(parents=True)
    (dest / "thermal").mkdir()
    views = []
    for fr in ds.frames:
        name = f"{Path(fr.file_path).stem.split('_')[0]}.png"
        raw = ds.read_raw(fr)
        if fr.modality == "rgb":
            cv2.imwrite(str(dest / "rgb" / name), cv2.cvtColor(raw, cv2.COLOR_RGB2BGR))
            views.append((name, fr))
        else:
            if thermal_8bit:    # what the published datasets hold: a colour-mapped picture
                grey = cv2.normalize(raw, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
                raw = cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO)
            cv2.imwrite(str(dest / "thermal" / name), raw)
            if register_thermal:
                views.append((f"thermal/{name}", fr))
    _write_model(dest / "sparse" / "0", views, ds.points_xyz, ds.points_rgb)
    return dest


def test_rgbt_folder_prepares_and_trains(sim, tmp_path, capsys):
    scene = _rgbt_folder(sim, tmp_path / "scene", register_thermal=True)
    assert recon_main(["prepare", str(scene), str(tmp_path / "data"), "--test-every", "4"]) == 0
    ds, truth = load_dataset(tmp_path / "data"), load_dataset(sim)
    assert len(ds.frames) == 24 and len(ds.split("rgb", "test")) == 3 and len(ds.split("thermal", "test")) == 3
    assert all(f.time == 0.0 for f in ds.frames) and ds.thermal_scale_k == pytest.approx(0.01)
    by_pose = {m: sorted((f.c2w_opencv()[:3, 3].round(6).tolist() for f in truth.frames if f.modality == m))
               for m in ("rgb", "thermal")}
    for m in ("rgb", "thermal"):      # the model's poses, as given
        got = sorted(f.c2w_opencv()[:3, 3].round(6).tolist() for f in ds.frames if f.modality == m)
        np.testing.assert_allclose(got, by_pose[m], atol=1e-5)
    np.testing.assert_array_equal(np.sort(ds.read_raw(ds.split("thermal", "train")[0]).ravel())[-10:] > 0, True)
    capsys.readouterr()
    assert recon_main(["run", str(tmp_path / "data"), "--out", str(tmp_path / "run"), *RUN]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())["metrics"]
    for m in ("rgb", "thermal"):
        assert np.isfinite(metrics[m]["psnr"]) and metrics[m]["psnr"] > PSNR_FLOOR_DB[m], metrics
    # `recon run` takes the folder itself: prepared into OUT/data (at full size), then trained
    assert recon_main(["run", str(scene), "--out", str(tmp_path / "direct"), *RUN]) == 0
    direct = load_dataset(tmp_path / "direct" / "data")
    assert direct.frames[0].width == ds.frames[0].width
    assert json.loads((tmp_path / "direct" / "metrics.json").read_text())["metrics"]["thermal"]["psnr"] > \
        PSNR_FLOOR_DB["thermal"]


def test_rgbt_thermal_from_the_calibration_and_with_times(sim, tmp_path):
    """A model registering only RGB: thermal = RGB pose o the calibrated extrinsic (--scale 1: the
    simulator is metric), times from a CSV; without an option it refuses, saying what to pass."""
    scene = _rgbt_folder(sim, tmp_path / "scene", register_thermal=False)
    assert recon_main(["prepare", str(scene), str(tmp_path / "refused")]) == 1
    meta = json.loads((sim / "sim_meta.json").read_text())
    cal = RigCalibration(Lens(**meta["rgb_intrinsics"]), Lens(**meta["thermal_intrinsics"]),
                         np.array(meta["thermal_from_rgb"])).save(tmp_path / "rig_calibration.json")
    rows = "".join(f"{i:06d}.png,{0.25 * i}\n" for i in range(12))
    (tmp_path / "times.csv").write_text("file,timestamp\n" + rows)
    assert recon_main(["prepare", str(scene), str(tmp_path / "data"), "--calibration", str(cal), "--scale", "1",
                       "--times", str(tmp_path / "times.csv")]) == 0
    ds, truth = load_dataset(tmp_path / "data"), load_dataset(sim)
    th = sorted((f for f in ds.frames if f.modality == "thermal"), key=lambda f: f.time)
    th_true = sorted((f for f in truth.frames if f.modality == "thermal"), key=lambda f: f.time)
    for a, b in zip(th, th_true):
        np.testing.assert_allclose(a.c2w_opencv(), b.c2w_opencv(), atol=1e-6)
        assert a.fx == pytest.approx(b.fx)
    assert [round(f.timestamp_s, 6) for f in th] == [0.25 * i for i in range(12)] and th[-1].time == 1.0


def test_rgbt_malformed_inputs_name_the_file(sim, tmp_path, capsys):
    scene = _rgbt_folder(sim, tmp_path / "scene", register_thermal=False, thermal_8bit=True)
    assert recon_main(["prepare", str(scene), str(tmp_path / "a"), "--thermal-aligned"]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, str(scene / "thermal" / "000000.png"))
    assert "--non-radiometric" in err
    assert recon_main(["prepare", str(scene), str(tmp_path / "b"), "--thermal-aligned", "--non-radiometric"]) == 0
    assert json.loads((tmp_path / "b" / "transforms.json").read_text())["thermal_radiometric"] is False
    grey = load_dataset(tmp_path / "b")
    assert grey.thermal_scale_k == 1.0 and 1 <= np.nanmin(grey.image(grey.frames[1])) <= 256
    (scene / "rgb" / "000005.png").unlink()                   # the model names an image not in rgb/
    capsys.readouterr()
    assert recon_main(["prepare", str(scene), str(tmp_path / "c"), "--thermal-aligned"]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, str(scene / "sparse" / "0" / "images.txt"))
    assert "000005.png" in err


# -- a radiometric frame folder + the phone video -> a session ----------------------------------------

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("sessions") / "s1"
    Capture(CaptureConfig(duration_s=3.0, out=path, progress=False)).run()
    return path


def _export_frames(session: Path, dest: Path) -> Path:
    """The session's thermal frames as another tool would leave them: 16-bit TIFFs and a CSV of
    Unix times (the clock of the phone's creation date)."""
    s = open_session(session)
    dest.mkdir()
    rows = ["file,timestamp"]
    for f in s.iter_thermal():
        name = f"frame_{f.index:05d}.tiff"
        cv2.imwrite(str(dest / name), f.counts)
        rows.append(f"{name},{s.host_ns_to_unix_s(f.record['host_ns']):.6f}")
    (dest.parent / "times.csv").write_text("\n".join(rows) + "\n")
    return dest


def test_radiometric_folder_imports_prepares_and_trains(session, tmp_path, capsys):
    frames = _export_frames(session, tmp_path / "frames")
    video = next((session / "rgb").glob("*.MOV"))
    out = tmp_path / "imported"
    assert rig_main(["import", "thermal", str(frames), "--out", str(out), "--timestamps",
                     str(tmp_path / "times.csv"), "--phone", str(video)]) == 0
    s, orig = open_session(out), open_session(session)
    assert s.closed and s.meta["imported"]["scale_k"] == 0.01 and "auto" in s.meta["imported"]["scale_from"]
    assert len(s.thermal) == len(orig.thermal) and len(s.rgb) == len(orig.rgb)
    np.testing.assert_array_equal(s.thermal_frame(5).counts, orig.thermal_frame(5).counts)
    assert s.thermal_frame(5).kelvin().mean() == pytest.approx(orig.thermal_frame(5).kelvin().mean())
    # sync without the lamp's markers (cross-correlation) lands near the marker sync of the original
    assert s.sync["method"] == "xcorr"
    assert abs(s.sync["rgb_offset_ms"] - orig.sync["rgb_offset_ms"]) < 30, (s.sync["files"], orig.sync["files"])
    capsys.readouterr()
    assert rig_main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["pairs"] >= 0.6 * len(s.thermal), info

    cal = simulated_calibration(orig).save(tmp_path / "rig_calibration.json")
    # metric scale: this SfM run's median depth is ~22 units at a true 0.6 m; checked against the truth below
    assert recon_main(["prepare", str(out), str(tmp_path / "data"), "--calibration", str(cal), "--scale", "0.027",
                       "--frames", "12", "--test-every", "4", "--downscale", "2"]) == 0
    ds = load_dataset(tmp_path / "data")
    assert len(ds.frames) >= 22 and ds.split("thermal", "test")
    report = json.loads((tmp_path / "data" / "prepare_report.json").read_text())
    truth = session_truth(orig)
    est = np.stack([f.c2w_opencv() for f in ds.frames if f.modality == "rgb"])
    gt = np.stack([truth.rgb_pose(orig.rgb[e["rgb_record"]]) for e in report["frame_list"]])
    e = pose_errors(est, gt)
    assert np.median(e["rotation_deg"]) < 2.0 and 0.5 < e["scale"] < 2.0, (e["rotation_deg"], e["scale"])
    capsys.readouterr()
    assert recon_main(["run", str(tmp_path / "data"), "--out", str(tmp_path / "run"), *RUN]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())["metrics"]
    assert np.isfinite(metrics["thermal"]["psnr"]) and metrics["thermal"]["psnr"] > PSNR_FLOOR_DB["thermal"], metrics


def test_frame_folder_malformed_inputs_name_the_file(tmp_path, capsys):
    good = tmp_path / "good"
    good.mkdir()
    counts = np.full((24, 32), 29500, np.uint16)
    for i in range(4):
        cv2.imwrite(str(good / f"f_{1_700_000_000_000 + 33 * i}.png"), counts)    # Unix ms in the name
    assert rig_main(["import", "thermal", str(good), "--out", str(tmp_path / "ok")]) == 0
    s = open_session(tmp_path / "ok")
    np.testing.assert_allclose([r["host_ns"] for r in s.thermal][:2], [1_700_000_000e9, 1_700_000_000.033e9],
                               rtol=0, atol=1e3)                 # float seconds: within 1 us
    capsys.readouterr()

    bad = tmp_path / "bad"
    shutil.copytree(good, bad)
    cv2.imwrite(str(bad / "f_1700000000000.png"), (counts // 256).astype(np.uint8))   # 8-bit
    assert rig_main(["import", "thermal", str(bad), "--out", str(tmp_path / "a")]) == 2
    _one_line_naming(capsys.readouterr().err, str(bad / "f_1700000000000.png"))
    assert not (tmp_path / "a").exists()

    cv2.imwrite(str(bad / "f_1700000000000.png"), cv2.merge([counts // 256] * 3).astype(np.uint8))  # colour
    assert rig_main(["import", "thermal", str(bad), "--out", str(tmp_path / "a")]) == 2
    _one_line_naming(capsys.readouterr().err, "f_1700000000000.png")

    csv = tmp_path / "times.csv"                                 # a frame without a timestamp
    csv.write_text("file,timestamp\n" + "".join(f"{p.name},{i * 0.04}\n" for i, p in
                                              enumerate(sorted(good.iterdir())[:-1])))
    assert rig_main(["import", "thermal", str(good), "--out", str(tmp_path / "b"), "--timestamps", str(csv)]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, str(csv))
    assert sorted(good.iterdir())[-1].name in err

    plain = tmp_path / "plain"                                   # no timestamp in the names
    plain.mkdir()
    for i in range(3):
        cv2.imwrite(str(plain / f"frame{i:03d}.png"), counts)
    assert rig_main(["import", "thermal", str(plain), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, str(plain / "frame000.png"))
    assert re.search(r"--timestamps CSV or --fps", err)
    assert rig_main(["import", "thermal", str(plain), "--out", str(tmp_path / "c"), "--fps", "9"]) == 0
