"""`recon prepare` end to end on short simulated-rig sessions: the dataset loads, thermal poses are
the RGB pose at the thermal frame's time composed with the rig extrinsic, and each way it can
fail says what was measured and what to recapture."""
import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from recon.cli import main as recon_main
from recon.data import load_dataset
from recon.prepare import REPORT_FILE, PrepareError, prepare_session
from recon.prepare.poses import interpolate_pose, pose_errors
from recon.prepare.simtruth import prepared_rgb_pose_errors
from rig.calibrate import simulated_calibration
from rig.capture.config import CaptureConfig
from rig.capture.session_capture import Capture
from rig.session import Session, open_session

FAST = dict(frames=12, test_every=4, downscale=2)


def _capture(path: Path, **sim) -> Path:
    Capture(CaptureConfig(duration_s=3.0, out=path, progress=False, **sim)).run()
    return path


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return _capture(tmp_path_factory.mktemp("sessions") / "s1")


@pytest.fixture(scope="module")
def prepared(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "s1"
    prepare_session(session, out, progress=None, **FAST)
    return out


def test_dataset_loads_with_thermal_poses_from_the_rig(prepared, session):
    ds = load_dataset(prepared)
    rgb, th = ([f for f in ds.frames if f.modality == m] for m in ("rgb", "thermal"))
    assert len(rgb) == len(th) >= 11 and ds.points_xyz is not None and len(ds.points_xyz) > 100
    assert ds.split("rgb", "test") and ds.split("thermal", "test")
    assert all(0 <= f.time <= 1 for f in ds.frames) and max(f.time for f in ds.frames) > 0.9
    assert rgb[0].width == 320 and th[0].width == 320                      # downscale 2 of 640x480
    # thermal pose = RGB path interpolated to the thermal frame's time, composed with the extrinsic
    cal = simulated_calibration(open_session(session))
    times = np.array([f.timestamp_s for f in rgb])
    path = np.stack([f.c2w_opencv() for f in rgb])
    for f in th:
        expected = interpolate_pose(times, path, f.timestamp_s) @ cal.rgb_from_thermal
        np.testing.assert_allclose(f.c2w_opencv(), expected, atol=1e-9)
        assert abs(f.fx - cal.thermal.fx / 2) < 1e-6 and abs(f.fy - cal.thermal.fy / 2) < 1e-6
    k = ds.image(th[0])
    h, w = k.shape                                                         # sync lamp box unmeasured
    assert 280 < np.nanmedian(k) < 320 and np.isnan(k[int(0.05 * h), int(0.05 * w)])


def test_recovered_poses_against_the_simulator(prepared, session):
    """Coarse on this 3 s test session (its keyframes are 0.2 s apart and blended: ghosted
    views); the figures in docs/prepare.md come from bench/prepare_accuracy.py."""
    e = prepared_rgb_pose_errors(open_session(session), prepared)
    assert np.median(e["rotation_deg"]) < 2.0 and np.median(e["position"]) < 0.02
    assert e["scale"] == pytest.approx(1.0, abs=0.02)                       # metric (simulator scale)


def test_report_has_the_numbers(prepared):
    r = json.loads((prepared / REPORT_FILE).read_text())
    assert r["status"] == "ok" and r["error"] is None
    assert r["frames"]["paired"] >= 80 and r["frames"]["selected"] == 12
    s = r["sfm"]
    for key in ("registered", "mean_reprojection_error_px", "mean_track_length", "pycolmap_s", "points",
                "path_jitter_deg_median"):
        assert key in s
    assert r["scale"]["method"] == "simulator" and 0.3 < r["scale"]["median_depth_m"] < 1.0
    assert r["calibration"]["method"] == "simulator" and any("simulator" in n for n in r["notes"])
    assert len(r["frame_list"]) == s["registered"]


def _without_truth(session: Path, dest: Path) -> Path:
    """The same session as if captured by a real rig: no simulator truth in session.json,
    events.jsonl or closed.json."""
    shutil.copytree(session, dest)
    closed = json.loads((dest / "closed.json").read_text())
    closed.pop("sim_truth")
    (dest / "closed.json").write_text(json.dumps(closed))
    meta = json.loads((dest / "session.json").read_text())
    meta.pop("sim_scene", None)
    (dest / "session.json").write_text(json.dumps(meta))
    events = [json.loads(line) for line in (dest / "events.jsonl").read_text().splitlines() if line.strip()]
    (dest / "events.jsonl").write_text("".join(json.dumps({k: v for k, v in e.items() if k != "sim_truth"}) + "\n"
                                               for e in events))
    return dest


def test_no_calibration_and_unknown_scale_refuse_with_advice(session, tmp_path, capsys):
    real = _without_truth(session, tmp_path / "real")
    assert recon_main(["prepare", str(real), str(tmp_path / "a"), "--frames", "12"]) == 1
    err = capsys.readouterr().err
    assert "no rig calibration" in err and "rig calibrate" in err
    report = json.loads((tmp_path / "a" / REPORT_FILE).read_text())
    assert report["status"] == "failed" and "no rig calibration" in report["error"]
    assert not (tmp_path / "a" / "transforms.json").exists()

    cal = simulated_calibration(open_session(session)).save(tmp_path / "rig_calibration.json")
    with pytest.raises(PrepareError) as exc:
        prepare_session(real, tmp_path / "b", progress=None, calibration=cal, **FAST)
    msg = str(exc.value)
    assert "metric scale unknown" in msg and "checkerboard" in msg and "--scale" in msg
    assert not (tmp_path / "b" / "transforms.json").exists()


def test_a_textureless_view_refuses(tmp_path, session):
    """The synthetic scene: warm blobs drifting over a smooth background, no SIFT features at all."""
    moving = _capture(tmp_path / "moving", sim_scene="synthetic")
    cal = simulated_calibration(open_session(session)).save(tmp_path / "rig_calibration.json")
    with pytest.raises(PrepareError) as exc:
        prepare_session(moving, tmp_path / "out", progress=None, calibration=cal, **FAST)
    msg = str(exc.value)
    assert "too few matches" in msg and "textureless" in msg and "Recapture" in msg
    report = json.loads((tmp_path / "out" / REPORT_FILE).read_text())
    assert report["status"] == "failed" and report["sfm"]["features_median"] >= 0


def _phone_sees(monkeypatch, change) -> None:
    """Every phone frame a session decodes becomes change(image (H, W, 3) uint8, t = its video time
    in s): what the phone would have recorded, fed to the real selection, SfM and checks."""
    decode = Session.iter_rgb

    def iter_rgb(self, start=0):
        for frame in decode(self, start):
            frame.image[:] = change(frame.image, frame.record["pts_s"])
            yield frame

    monkeypatch.setattr(Session, "iter_rgb", iter_rgb)


def _board(h: int, w: int, seed: int = 0) -> np.ndarray:
    """(h, w, 3) uint8 texture with blobs of 8 and 24 px: plenty of SIFT features."""
    rng = np.random.default_rng(seed)
    out = np.zeros((h, w, 3), np.float32)
    for cell in (8, 24):
        small = rng.uniform(0, 255, (h // cell + 2, w // cell + 2, 3)).astype(np.float32)
        out += cv2.resize(small, None, fx=cell, fy=cell, interpolation=cv2.INTER_CUBIC)[:h, :w] / 2
    return np.clip(out, 0, 255).astype(np.uint8)


def _passing_object(start_s: float, end_s: float, fill: float = 0.9):
    """A long textured object passing close to the camera between start_s and end_s: it covers the
    lower `fill` of the view and slides 4 view widths a second, so frames 0.25 s apart share none
    of its texture and only the top strip of the static scene."""
    board = _board(480, 640 * 14)

    def change(image: np.ndarray, t: float) -> np.ndarray:
        if not start_s <= t <= end_s:
            return image
        h, w = image.shape[:2]
        x = int(4 * 640 * t) % (board.shape[1] - 640)
        out = image.copy()
        top = round(h * (1 - fill))
        out[top:] = cv2.resize(board[:, x:x + 640], (w, h))[top:]
        return out
    return change


def _span(text: str) -> tuple[float, float]:
    """'1.0-1.4' or '1.2' (recover.spans) -> (first, last) s."""
    first, _, last = text.partition("-")
    return float(first), float(last or first)


def test_a_view_filled_by_a_moving_object_refuses_saying_so(session, tmp_path, monkeypatch):
    _phone_sees(monkeypatch, _passing_object(1.0, 2.0))            # a third of the 3 s take
    with pytest.raises(PrepareError) as exc:
        prepare_session(session, tmp_path / "out", progress=None, **FAST)
    msg = str(exc.value)
    registered, dropped = re.search(r"registered (\d+)/12 frames .* unregistered at ([\d.-]+) s", msg).groups()
    assert int(registered) < 0.8 * 12
    t0, t1 = _span(dropped)
    assert 0.9 <= t0 < t1 <= 2.1
    assert "moving objects" in msg and "Recapture with most of the static scene in view" in msg
    assert "dark" not in msg and "textureless" not in msg
    report = json.loads((tmp_path / "out" / REPORT_FILE).read_text())
    assert report["status"] == "failed" and report["sfm"]["features_median"] > 200   # texture was not the issue


def test_a_short_moving_object_drops_its_frames_with_a_warning(session, tmp_path, monkeypatch):
    """The "fewer frames" fallback: >= 80 % registered keeps the registered time steps only."""
    # one frame covered: SfM may lose a neighbour too (with two covered, 9 of 12 registered in a
    # fresh-clone CI run and once here), and 10 of 12 is still >= 80 %
    _phone_sees(monkeypatch, _passing_object(1.0, 1.15))
    prepare_session(session, tmp_path / "out", progress=None, **FAST)
    report = json.loads((tmp_path / "out" / REPORT_FILE).read_text())
    kept = report["frames"]["registered"]
    assert 0.8 * 12 <= kept < 12 and report["status"] == "ok"
    warning = next(w for w in report["warnings"] if "did not register" in w)
    t0, t1 = _span(re.match(rf"{12 - kept} of 12 frames did not register \(at ([\d.-]+) s", warning).group(1))
    assert 0.9 <= t0 <= t1 <= 1.6 and f"keeps the {kept} registered time steps" in warning
    ds = load_dataset(tmp_path / "out")
    times = [f.timestamp_s for f in ds.frames if f.modality == "rgb"]
    assert len(times) == len(report["frame_list"]) == kept
    assert len([f for f in ds.frames if f.modality == "thermal"]) == kept
    assert not any(t0 <= t <= t1 for t in times)                  # the dropped times are gone


def test_dark_frames_warn_and_failed_matching_blames_the_light(session, tmp_path, monkeypatch):
    """The phone at 1 % light with sensor noise: the report warns (median grey level < 0.3) and the
    refusal says to add light."""
    rng = np.random.default_rng(0)
    _phone_sees(monkeypatch, lambda image, t: np.clip(image * 0.01 + rng.normal(2, 2, image.shape), 0, 255
                                                      ).astype(np.uint8))
    with pytest.raises(PrepareError) as exc:
        prepare_session(session, tmp_path / "out", progress=None, **FAST)
    report = json.loads((tmp_path / "out" / REPORT_FILE).read_text())
    grey = report["frames"]["median_brightness"]
    assert grey < 0.03
    assert any(w.startswith(f"low light: median grey level {grey:.2f} (< 0.3)") for w in report["warnings"])
    assert f"The phone frames are dark (median grey level {grey:.2f})" in str(exc.value)
    assert str(exc.value).endswith("recapture with more light") and "too few matches" in str(exc.value)


def test_bad_arguments(tmp_path, session, capsys):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    assert recon_main(["prepare", str(session), str(tmp_path / "full")]) == 2
    assert "not empty" in capsys.readouterr().err
    assert recon_main(["prepare", str(session), str(tmp_path / "o"), "--frames", "1"]) == 2
    assert recon_main(["prepare", str(tmp_path / "nothing"), str(tmp_path / "o2")]) == 1
    assert "not a thermal4d session" in capsys.readouterr().err
