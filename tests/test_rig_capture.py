"""`rig capture` / `rig info` / `rig devices` end to end: simulated rig, the fake GigE camera with
a phone drop folder and a sync box, and kill -9 in the middle of a capture."""
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rig.capture.config import CaptureConfig
from rig.capture.progress import progress_line
from rig.capture.session_capture import Capture
from rig.cli import main as rig_main
from rig.info import session_info
from rig.session import open_session
from tests.fakes.fake_gige import FakeConfig, FakeGigECamera
from tests.fakes.fake_phone import drop_slowly, write_mov
from tests.fakes.fake_syncbox import FakeSyncBox

ROOT = Path(__file__).resolve().parents[1]


def test_simulated_rig_capture_and_info(tmp_path, capsys):
    """The simulated world (rig.sim) through the whole capture path."""
    # files of 4 s: with ~1 s lamp pulses a file needs several in view to be placed unambiguously
    cfg = CaptureConfig(duration_s=8.0, out=tmp_path / "s", sim_segment_s=4.0, sync_every_s=2.0, progress=False)
    Capture(cfg).run()
    assert rig_main(["info", str(tmp_path / "s"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    th, rgb = info["streams"]["thermal"], info["streams"]["rgb"]
    assert info["closed"] and 7.0 < info["duration_s"] < 9.5
    assert th["complete"] >= 100 and th["incomplete"] == 0 and th["dropped"] == 0 and th["fps"] == pytest.approx(30, abs=3)
    assert rgb["frames"] >= 90 and rgb["files"] >= 2 and rgb["fps"] == pytest.approx(30, abs=3)
    assert info["sync"]["method"] == "markers" and info["pairs"] > 80
    s = open_session(tmp_path / "s")
    f = next(s.iter_thermal())
    assert f.counts.shape == (480, 640) and 280 < f.kelvin().mean() < 340
    img = next(s.iter_rgb()).image
    assert img.shape == (480, 640, 3)
    # the phone's clock error is recovered (simulation ground truth is in the summary)
    truth = {t["file"]: t for t in s.summary["sim_truth"]}
    for fs in s.sync["files"]:
        t = truth[Path(fs["file"]).name]
        err_ms = (fs["offset_s"] - (t["true_start_host_s"] - t["nominal_start_host_s"])) * 1e3
        assert abs(err_ms) < 16.7, (fs, err_ms)


def test_capture_from_gige_phone_folder_and_syncbox(tmp_path):
    drop = tmp_path / "drop"
    drop.mkdir()
    movie = write_mov(tmp_path / "IMG_0042.MOV", (np.full((48, 64, 3), i * 9, np.uint8) for i in range(25)),
                      [i / 25 for i in range(25)], time.time())
    box = FakeSyncBox()
    with FakeGigECamera(FakeConfig(width=160, height=120, loss=0.01)) as fake:
        threading.Timer(0.5, drop_slowly, args=(movie, drop), kwargs={"chunk": 2048, "delay_s": 0.01}).start()
        code = rig_main(["capture", "--duration", "3", "--camera", fake.url, "--phone-drop", str(drop),
                         "--syncbox", box.port, "--settle", "0.3", "--out", str(tmp_path / "s"), "--quiet"])
    box.close()
    assert code == 0
    s = open_session(tmp_path / "s")
    assert s.closed and not s.meta["simulated"] and s.meta["thermal"]["device"]["serial"] == "FAKE0700"
    # 3 s at 30 Hz, less a late start on a busy host (69 on a host 4x slower than usual)
    assert 45 <= len(s.thermal) <= 100
    assert sum(r["complete"] for r in s.thermal) == len(s.thermal)
    assert {r["ir_format"] for r in s.thermal} == {"TemperatureLinear10mK"}
    assert any(r["resent_packets"] for r in s.thermal)                 # 1 % loss, recovered
    assert s.summary["stats"]["gige_stream"]["resend_requests"] > 0
    assert len(s.rgb) == 25 and s.rgb[0]["file"] == "rgb/IMG_0042.MOV"
    assert (tmp_path / "s" / "rgb" / "IMG_0042.MOV").read_bytes() == movie.read_bytes()
    markers = [e for e in s.events if e["event"] == "marker"]
    assert len(markers) >= 2 and any(e["event"] == "syncbox_clock" for e in s.events)
    info = session_info(s)
    assert info["streams"]["thermal"]["incomplete"] == 0 and info["markers"] == len(markers)


def test_nuc_events_are_written_to_events_jsonl(tmp_path):
    """The fake camera pauses for automatic NUCs (0.3 s every 1.5 s) and for one commanded NUC
    (acked after a 0.6 s PENDING_ACK): each shows in events.jsonl with host times."""
    with FakeGigECamera(FakeConfig(width=160, height=120, nuc_period_s=1.5, nuc_duration_s=0.3)) as fake:
        cap = Capture(CaptureConfig(duration_s=4.0, out=tmp_path / "s", camera=fake.url, progress=False))
        threading.Timer(2.0, lambda: cap.dev.camera.nuc()).start()
        cap.run()
        nucs = fake.stats["nucs"]
    s = open_session(tmp_path / "s")
    events = [e for e in s.events if e["event"] == "nuc"]
    commands = [e for e in events if e["source"] == "command"]
    pauses = [e for e in events if e["source"] == "pause"]
    assert len(commands) == 1 and commands[0]["done_host_ns"] - commands[0]["host_ns"] >= 0.5e9
    # NUCs pause 0.3-0.6 s (shorter pauses: the fake's sender thread was late on a busy machine)
    nuc_pauses = [p for p in pauses if p["gap_s"] > 0.25]
    assert 2 <= len(nuc_pauses) <= nucs and not any(r["dropped_before"] for r in s.thermal)
    frames = {r["i"]: r for r in s.thermal}
    for p in pauses:
        assert 1.5 / 30 < p["gap_s"] < 1.0 and frames[p["frame"]]["host_ns"] == p["end_host_ns"]
        assert p["end_host_ns"] - p["host_ns"] == pytest.approx(p["gap_s"] * 1e9, abs=0.05e9)
    # the commanded NUC paused the stream while it ran
    c = commands[0]
    assert any(p["host_ns"] <= c["done_host_ns"] and p["end_host_ns"] >= c["host_ns"] for p in nuc_pauses)
    assert len(pauses) == sum(g["kind"] == "pause (NUC)" for g in s.sync["thermal_gaps"])


def test_phone_drop_alone_records_beside_a_simulated_thermal_camera(tmp_path, capsys):
    """Only --phone-drop named: the simulation supplies the thermal camera, no simulated phone or lamp."""
    drop = tmp_path / "drop"
    drop.mkdir()
    movie = write_mov(tmp_path / "IMG_0007.MOV", (np.full((48, 64, 3), i * 9, np.uint8) for i in range(25)),
                      [i / 25 for i in range(25)], time.time())
    threading.Timer(0.3, drop_slowly, args=(movie, drop), kwargs={"chunk": 4096, "delay_s": 0.01}).start()
    code = rig_main(["capture", "--duration", "2.5", "--phone-drop", str(drop), "--settle", "0.3",
                     "--sim-scene", "synthetic", "--out", str(tmp_path / "s"), "--quiet"])
    assert code == 0
    s = open_session(tmp_path / "s")
    assert s.closed and not s.meta["simulated"] and s.meta["simulated_parts"] == ["thermal"]
    assert s.meta["thermal"]["source"] == "simulated" and s.meta["rgb"]["source"] == str(drop)
    assert 50 <= len(s.thermal) <= 90 and all(r["complete"] for r in s.thermal)
    assert len(s.rgb) == 25 and {r["file"] for r in s.rgb} == {"rgb/IMG_0007.MOV"}
    assert not (tmp_path / ".s.sim-phone-drop").exists()            # no simulated phone
    assert not any(e["event"] == "marker" for e in s.events)      # no simulated lamp
    assert "sim_scene" not in s.meta and not s.summary["stats"]["errors"]
    # a 1 s phone file has no residual, and rig info says why
    capsys.readouterr()
    assert rig_main(["info", str(tmp_path / "s")]) == 0
    assert "residual - (phone files too short for a residual: the longest is 1.0 s" in capsys.readouterr().out


def test_syncbox_alone_records_beside_a_simulated_thermal_camera(tmp_path):
    box = FakeSyncBox()
    try:
        code = rig_main(["capture", "--duration", "2.5", "--syncbox", box.port, "--sim-scene", "synthetic",
                         "--out", str(tmp_path / "s"), "--quiet"])
    finally:
        box.close()
    assert code == 0
    s = open_session(tmp_path / "s")
    assert s.meta["simulated_parts"] == ["thermal"] and s.meta["syncbox"]["port"] == box.port
    assert len(s.thermal) >= 50 and not s.rgb
    markers = [e for e in s.events if e["event"] == "marker"]
    assert markers and all("box_us" in e and not e.get("simulated") for e in markers)


def test_progress_line_shows_both_streams_and_their_losses():
    streams = {"thermal": {"frames": 1802, "fps": 29.96, "incomplete": 3, "dropped": 1, "resent": 40},
               "rgb": {"frames": 1750, "files": 6, "fps": 30.04, "dropped": 2}}
    line = progress_line(60.04, 60, streams, 118, 2.25, 140.4)
    assert line == ("  60.0/60 s | thermal 1802 (30.0 fps) incomplete 3 dropped 1 resent 40 | rgb 1750 in 6 files "
                    "(30.0 fps) dropped 2 | markers 118 | sync residual 2.2 ms offset +140 ms")
    streams["thermal"].pop("resent")
    line = progress_line(1.5, 5, streams, 0, None, None)
    assert "incomplete 3 dropped 1 |" in line and line.endswith("sync residual -")


def test_final_progress_line_reports_the_real_rates(tmp_path, capsys):
    """A 3 s simulated capture ends with the recording's time and rates (device clock, phone
    PTS), not the arrivals of its last seconds (which fall to 0 while the capture shuts down)."""
    Capture(CaptureConfig(duration_s=3.0, out=tmp_path / "s", sim_scene="synthetic", sim_segment_s=2.0)).run()
    final = capsys.readouterr().err.split("\r")[-1]
    m = re.match(r"\s*([\d.]+)/3 s \| thermal (\d+) \(\s*([\d.]+) fps\) incomplete 0 dropped 0 resent 0 "
                 r"\| rgb (\d+) in (\d+) files \(\s*([\d.]+) fps\) dropped (\d+) \| markers (\d+)", final)
    assert m, final
    elapsed, th, th_fps, rgb, files, rgb_fps, rgb_dropped, markers = map(float, m.groups())
    assert 3.0 <= elapsed < 3.8 and th >= 75 and th_fps == pytest.approx(30, abs=1.5)
    assert rgb >= 60 and files >= 1 and rgb_fps == pytest.approx(30, abs=1.5) and markers >= 2


def test_kill_9_during_capture_keeps_every_committed_frame(tmp_path):
    out = tmp_path / "s"
    proc = subprocess.Popen([sys.executable, "-m", "rig", "capture", "--duration", "60", "--out", str(out),
                             "--sim-scene", "synthetic", "--quiet"], cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    index = out / "thermal.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if index.exists() and index.read_bytes().count(b"\n") >= 60:
            break
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    s = open_session(out)
    assert not s.closed and len(s.thermal) >= 60
    n = 0
    for f in s.iter_thermal():
        assert f.counts.shape == (480, 640) and f.counts.min() > 0
        n += 1
    assert n == len(s.thermal)
    info = session_info(s)                     # a crashed session still summarises
    assert info["streams"]["thermal"]["frames"] == n and info["closed"] is False


def test_cli_errors_are_clear(tmp_path, capsys):
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("x")
    assert rig_main(["capture", "--duration", "1", "--out", str(tmp_path / "busy"), "--quiet"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert rig_main(["capture", "--duration", "1", "--camera", "usb://x", "--out", str(tmp_path / "c")]) == 2
    assert "gige://" in capsys.readouterr().err
    assert rig_main(["info", str(tmp_path)]) == 2
    assert "not a thermal4d session" in capsys.readouterr().err


def test_devices_lists_what_it_can(capsys):
    assert rig_main(["devices", "--json", "--timeout", "0.2"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d) == {"gige", "serial", "phones", "phones_note"}
    assert all("port" in p for p in d["serial"])
    if not d["phones"]:
        assert d["phones_note"] is None or "usb" in d["phones_note"].lower()


def test_devices_without_libusb_says_what_to_install(monkeypatch, capsys):
    """pyusb raises NoBackendError where libusb-1.0 is missing: `rig devices` still lists the
    rest and says what to install."""
    usb_core = pytest.importorskip("usb.core")

    def no_backend(*args, **kw):
        raise usb_core.NoBackendError("No backend available")
    monkeypatch.setattr(usb_core, "find", no_backend)
    assert rig_main(["devices", "--timeout", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "Phones (Apple USB):\n  none (libusb is not installed (apt-get install libusb-1.0-0))" in out
    assert "GigE Vision cameras:" in out and "Serial ports:" in out
    assert rig_main(["devices", "--json", "--timeout", "0.1"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["phones"] == [] and "libusb-1.0-0" in d["phones_note"]
