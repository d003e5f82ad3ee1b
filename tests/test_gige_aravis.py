"""The GigE Vision client against a real peer: Aravis's fake GigE camera (Debian `aravis-tools`).

One fake-camera process per module (its register state and frame counter persist while it
lives); `restart()` gives a test a fresh one. Skipped only where the binary is missing.
"""
import shutil
import socket
import subprocess
import time

import numpy as np
import pytest

from rig.drivers.gige import ControlConfig, GigECamera, GigEDevice, GvcpError, GvcpTimeout, discover
from rig.drivers.gige import gvcp
from rig.drivers.gige.device import broadcast_addresses
from rig.drivers.gige.features import fetch_genicam_xml

ARV_FAKE = shutil.which("arv-fake-gv-camera-0.8")
pytestmark = pytest.mark.skipif(ARV_FAKE is None, reason="arv-fake-gv-camera-0.8 not found "
                                "(make system-deps installs Debian's aravis-tools)")
URL = "gige://127.0.0.1"


class AravisFake:
    def __init__(self):
        self.proc = None

    def start(self, *args: str) -> None:
        self.proc = subprocess.Popen([ARV_FAKE, "-i", "127.0.0.1", *args],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                pytest.fail(f"arv-fake-gv-camera-0.8 exited ({self.proc.stderr.read().decode()[-300:]}); "
                            "is another instance holding UDP 127.0.0.1:3956?")
            if any(d.manufacturer == "Aravis" for d in discover(["127.0.0.1"], timeout_s=0.2)):
                time.sleep(0.2)
                if self.proc.poll() is None:
                    return
        pytest.fail("arv-fake-gv-camera-0.8 did not answer discovery within 10 s")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def restart(self, *args: str) -> None:
        self.stop()
        self.start(*args)


@pytest.fixture(scope="module")
def aravis():
    fake = AravisFake()
    fake.start()
    yield fake
    fake.stop()


def stream(cam: GigECamera, pixel_format: str, n: int, width=640, height=480, fps=30.0):
    f = cam.features
    f.set("Width", width)
    f.set("Height", height)
    f.set("PixelFormat", pixel_format)
    f.set("AcquisitionFrameRate", fps)
    s = cam.start_stream()
    frames = [s.get(timeout=2.0) for _ in range(n)]
    cam.stop_acquisition()
    return frames, s.stats


def test_block_ids_start_near_65400_and_wrap(aravis):
    aravis.restart()                      # a fresh counter
    with GigECamera.open(URL) as cam:
        frames, stats = stream(cam, "Mono8", 170, width=64, height=64, fps=250.0)
    ids = [f.block_id for f in frames]
    assert 65000 < ids[0] <= 65535
    wrap = ids.index(65535)
    assert ids[wrap + 1] == 1              # 0 is not a block id
    assert np.all(np.diff(ids[:wrap + 1]) == 1) and np.all(np.diff(ids[wrap + 1:]) == 1)
    assert stats.dropped == 0 and stats.late_packets == 0 and stats.resyncs == 0


def test_discovery_and_identity(aravis):
    found = [d for d in discover(["127.0.0.1"]) if d.manufacturer == "Aravis"]
    assert len(found) == 1
    d = found[0]
    assert (d.model, d.serial, d.ip) == ("Fake", "GV01", "127.0.0.1")


def _can_broadcast() -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        try:
            s.sendto(b"", ("255.255.255.255", 9))          # discard port
        except OSError:
            return False
    return True


def test_discovery_by_broadcast_only(aravis):
    """No unicast address given: the limited broadcast (and each interface's) reaches the fake,
    which reports 127.0.0.1 as its own address whatever route its answer took."""
    if not _can_broadcast():
        pytest.skip("no route for 255.255.255.255 on this machine")
    addresses = broadcast_addresses() + ["255.255.255.255"]
    assert "127.0.0.1" not in addresses
    found = [d for d in discover(addresses) if d.manufacturer == "Aravis"]
    assert len(found) == 1 and (found[0].model, found[0].serial, found[0].ip) == ("Fake", "GV01", "127.0.0.1")
    with GigEDevice(found[0].ip) as dev:
        assert dev.read_reg(0x1F0) == 0x12345678


def test_genicam_xml_and_features(aravis):
    with GigEDevice("127.0.0.1") as dev:
        xml = fetch_genicam_xml(dev)
        assert xml.lstrip().startswith("<?xml") and 'VendorName="Aravis"' in xml
        assert dev.read_reg(0x1F0) == 0x12345678            # the fake's TestRegister
    with GigECamera.open(URL) as cam:
        f = cam.features
        f.set("Width", 320)
        f.set("PixelFormat", "Mono16")
        assert f.get("Width") == 320 and f.get("PayloadSize") == 320 * f.get("Height") * 2
        assert not cam.resend_supported and cam.tick_hz == 1_000_000_000


def test_heartbeat_keeps_control_and_others_are_ignored(aravis):
    ctrl = ControlConfig(timeout_s=0.1, retries=1, heartbeat_period_s=0.15)
    with GigEDevice("127.0.0.1", config=ctrl) as owner, GigEDevice("127.0.0.1", config=ctrl) as other:
        owner.take_control()
        owner.write_reg(gvcp.Reg.HEARTBEAT_TIMEOUT, 500)
        time.sleep(1.5)                                       # three heartbeat timeouts
        assert not owner.control_lost.is_set()
        # the Aravis fake drops a non-controller's write silently; a real camera says ACCESS_DENIED
        with pytest.raises((GvcpTimeout, GvcpError)):
            other.write_reg(gvcp.Reg.CCP, gvcp.CCP_CONTROL)
        assert owner.read_reg(gvcp.Reg.CCP) & gvcp.CCP_CONTROL
        owner.write_reg(gvcp.Reg.HEARTBEAT_TIMEOUT, 3000)
        owner.release_control()
        other.take_control()                                  # free once released
        other.release_control()


@pytest.mark.parametrize("pixel_format", ["Mono8", "Mono16"])
def test_streams_640x480_at_30hz(aravis, pixel_format):
    with GigECamera.open(URL) as cam:
        frames, stats = stream(cam, pixel_format, 45)
    complete = [f for f in frames if f.complete]
    assert len(complete) >= 0.95 * len(frames)
    yy, xx = np.mgrid[0:480, 0:640]
    for f in complete[::5]:
        a = f.array().astype(np.int64)
        start = a[0, 0] if pixel_format == "Mono8" else a[0, 0] // 256
        # Aravis's diagonal ramp: Mono8 (x + y + frame) % 255; Mono16 256 (x + y + frame) % 65535
        expect = (xx + yy + start) % 255 if pixel_format == "Mono8" else (256 * (xx + yy + start)) % 65535
        assert np.array_equal(a, expect)
    ts = np.array([f.timestamp for f in complete], float)
    dt = np.diff(ts) / 1e9
    assert np.all(dt > 0) and np.median(dt) == pytest.approx(1 / 30, abs=0.005)
    assert abs(ts[-1] / 1e9 - time.time()) < 60          # the fake stamps wall-clock ns


def test_lossy_peer_without_resend_is_counted(aravis):
    aravis.restart("-r", "20")                   # 2 % of GVSP packets lost, no PACKETRESEND
    try:
        with GigECamera.open(URL) as cam:
            frames, stats = stream(cam, "Mono8", 20, width=320, height=240)
    finally:
        aravis.restart()
    bad = [f for f in frames if not f.complete]
    assert bad and stats.resend_requests == 0
    assert stats.missing_packets >= len(bad) and all(f.missing_packets > 0 for f in bad)


def test_capture_with_a_profile_the_camera_lacks_is_one_line(aravis, tmp_path, capsys):
    """Aravis's fake is a standard GigE Vision camera with no FLIR radiometric features: forcing
    the FLIR profile is refused in one line naming the camera and the missing feature (exit 2),
    leaving no session behind and the camera free."""
    from rig.cli import main as rig_main
    out = tmp_path / "s"
    assert rig_main(["capture", "--camera", URL, "--profile", "flir-irformat", "--duration", "2", "--out", str(out),
                     "--quiet"]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("rig capture:") and "Aravis" in lines[0] and "IRFormat" in lines[0]
    assert not out.exists() or not any(out.iterdir())
    assert any(d.manufacturer == "Aravis" for d in discover(["127.0.0.1"], timeout_s=0.5))   # still usable


def test_the_whole_chain_on_a_generic_camera(aravis, tmp_path, capsys):
    """Issue 15: `rig capture --camera gige://127.0.0.1` records Aravis's fake with the generic
    profile (counts, marked non-radiometric), `rig info --json` reports complete frames at the
    fake's rate, `recon prepare` refuses the phone-less session in one line."""
    import json
    from recon.cli import main as recon_main
    from rig.cli import main as rig_main
    aravis.restart()
    out = tmp_path / "s"
    assert rig_main(["capture", "--camera", URL, "--duration", "4", "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert rig_main(["info", str(out), "--json"]) == 0
    th = json.loads(capsys.readouterr().out)["streams"]["thermal"]
    with GigECamera.open(URL) as cam:
        rate = float(cam.features.get("AcquisitionFrameRate"))
    assert th["profile"] == "generic" and th["radiometric"] is False and th["ir_formats"] == ["Counts"]
    assert th["complete"] >= 0.95 * th["frames"] and th["frames"] >= 0.9 * 4 * rate, th
    assert abs(th["fps"] - rate) < 0.1 * rate, (th["fps"], rate)
    meta = json.loads((out / "session.json").read_text())["thermal"]
    assert meta["packet_size"] == 1500 and meta["packet_size_tested"] is False      # the fake fires no test packet
    assert recon_main(["prepare", str(out), str(tmp_path / "data")]) != 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "no phone video" in err[0] and str(out) in err[0], err
