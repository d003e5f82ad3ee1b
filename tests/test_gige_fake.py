"""The GigE Vision client against the project's fake FLIR A700 (UDP loopback)."""
import time

import numpy as np
import pytest

from rig.drivers import flir
from rig.drivers.gige import ControlConfig, GigECamera, GigEDevice, GvcpError, StreamConfig, discover
from rig.drivers.gige import gvcp
from rig.drivers.gige.features import fetch_genicam_xml
from rig.sync import fit_clock
from tests.fakes.fake_gige import XML_PATH, FakeConfig, FakeGigECamera, synthetic_scene, world_scene

W, H = 160, 120


@pytest.fixture
def make_fake():
    fakes = []

    def make(**kw):
        kw.setdefault("width", W)
        kw.setdefault("height", H)
        fake = FakeGigECamera(FakeConfig(**kw)).start()
        fakes.append(fake)
        return fake
    yield make
    for f in fakes:
        f.stop()


def collect(cam, n, timeout=2.0):
    return [cam.next_frame(timeout=timeout) if hasattr(cam, "next_frame") else cam.stream.get(timeout=timeout)
            for _ in range(n)]


@pytest.mark.parametrize("zipped", [True, False])
def test_discovery_and_genicam_xml(make_fake, zipped):
    fake = make_fake(zipped_xml=zipped)
    found = discover([fake.host], port=fake.port)
    assert len(found) == 1 and found[0].model == "FLIR A700 (thermal4d fake)" and found[0].serial == "FAKE0700"
    with GigEDevice(fake.host, fake.port) as dev:
        assert fetch_genicam_xml(dev) == XML_PATH.read_text()


def test_features_through_gvcp(make_fake):
    fake = make_fake()
    with GigECamera.open(fake.url) as cam:
        f = cam.features
        assert (f.get("Width"), f.get("Height"), f.get("PixelFormat")) == (W, H, "Mono16")
        assert f.get("PayloadSize") == W * H * 2
        f.set("IRFormat", "TemperatureLinear100mK")
        assert fake._get(0x2001C) == 1                       # the register the XML maps it to
        f.set("ObjectEmissivity", 0.8)
        assert f.get("ObjectEmissivity") == pytest.approx(0.8)
        assert cam.resend_supported and cam.tick_hz == 1_000_000_000


def test_second_controller_gets_access_denied(make_fake):
    fake = make_fake()
    with GigEDevice(fake.host, fake.port) as first, GigEDevice(fake.host, fake.port) as second:
        first.take_control()
        with pytest.raises(GvcpError) as err:
            second.write_reg(gvcp.Reg.CCP, gvcp.CCP_CONTROL)
        assert err.value.status == gvcp.Status.ACCESS_DENIED
        assert second.read_reg(gvcp.Reg.CCP) == gvcp.CCP_CONTROL     # reads stay open to everyone
        first.release_control()
        second.take_control()                                        # free again
        second.release_control()


def test_heartbeat_keeps_control_and_loss_is_noticed(make_fake):
    fake = make_fake(heartbeat_timeout_ms=300)
    dev = GigEDevice(fake.host, fake.port, ControlConfig(heartbeat_period_s=0.08, timeout_s=0.1, retries=1))
    dev.take_control()
    time.sleep(0.8)                                     # > 2 heartbeat timeouts
    assert not dev.control_lost.is_set() and fake.controller is not None
    dev._stop_heartbeat.set()                            # heartbeat stops (e.g. host hung) ...
    dev._heartbeat.join()
    time.sleep(0.5)
    assert fake.controller is None                       # ... the device releases control
    with GigEDevice(fake.host, fake.port) as other:
        other.take_control()                             # and someone else may take it
        other.release_control()
    dev.control_lost.set()
    dev.close()


def test_writemem_round_trip_and_a_retried_request_keeps_its_id(make_fake):
    fake = make_fake()
    with GigEDevice(fake.host, fake.port, ControlConfig(timeout_s=0.1, retries=3)) as dev:
        data = bytes(range(256)) * 4 + b"xyz"            # three WRITEMEMs of <= 512 B, unaligned end
        dev.write_mem(0x20400, data)
        assert dev.read_mem(0x20400, len(data)) == data
        assert fake.stats[f"cmd_{gvcp.Command.WRITEMEM:04x}"] == 3
        fake.commands.clear()
        fake.drop_next_commands = 2                      # the first two tries are lost
        dev.write_mem(0x20800, b"ABCD")
        tries = [rid for cmd, rid in fake.commands if cmd == gvcp.Command.WRITEMEM]
        assert len(tries) == 3 and len(set(tries)) == 1 and dev.stats.retries == 2
        assert dev.read_mem(0x20800, 4) == b"ABCD"
        assert fake.commands[-1][1] == gvcp.next_req_id(tries[0])     # the next request moves on


def test_pending_ack_extends_the_wait(make_fake):
    fake = make_fake(nuc_pending_ms=500)
    ctrl = ControlConfig(timeout_s=0.15, retries=0)      # would time out without PENDING_ACK
    with GigECamera.open(fake.url, control=ctrl) as cam:
        t0 = time.monotonic()
        flir.FlirA700(cam).nuc()
        assert time.monotonic() - t0 >= 0.45
        assert cam.device.stats.pending_acks == 1 and cam.device.stats.retries == 0


def test_stream_frames_match_the_scene(make_fake):
    fake = make_fake()
    scene = synthetic_scene(W, H)
    with GigECamera.open(fake.url) as cam:
        a700 = flir.FlirA700(cam)
        a700.configure("TemperatureLinear10mK", W, H)
        a700.start(StreamConfig(packet_size=1400))
        frames = collect(a700, 10)
        stats = cam.stream.stats
    assert all(f.complete for f in frames) and stats.dropped == 0 and stats.incomplete == 0
    ids = [f.block_id for f in frames]
    assert ids == list(range(ids[0], ids[0] + 10))
    # the fake renders scene(t) at t = device seconds since its start: decode and compare
    for f in frames[:3]:
        t = f.timestamp / 1e9 - fake.config.clock_offset_s
        assert np.abs(a700.kelvin(f) - scene(t)).max() <= 0.006      # 10 mK quantisation
    assert {f.meta["ir_format"] for f in frames} == {"TemperatureLinear10mK"}


def test_streams_the_simulated_world(make_fake):
    scene = world_scene(W, H)
    fake = make_fake(source=scene)
    with GigECamera.open(fake.url) as cam:
        a700 = flir.FlirA700(cam)
        a700.configure("TemperatureLinear10mK", W, H)
        a700.start()
        f = collect(a700, 3)[-1]
    t = f.timestamp / 1e9 - fake.config.clock_offset_s
    k = a700.kelvin(f)
    assert 250 < k.min() and k.max() < 400 and k.std() > 1            # a scene, not a constant
    assert np.abs(k - scene(t)).max() <= 0.005 + 1e-3


def test_one_percent_loss_reorder_duplicates_recovered_by_resend(make_fake):
    fake = make_fake(loss=0.02, reorder=0.02, duplicate=0.02, width=320, height=240)
    with GigECamera.open(fake.url) as cam:
        cam.start_stream(StreamConfig(packet_size=1000))
        frames = collect(cam, 30)
        stats = cam.stream.stats
    assert fake.stats["lost_packets"] > 50
    assert sum(f.complete for f in frames) == 30
    assert stats.resend_requests > 0 and stats.resent_packets > 0 and stats.duplicates > 0


def test_without_resend_losses_are_counted(make_fake):
    fake = make_fake(loss=0.05, resend=False)
    with GigECamera.open(fake.url) as cam:
        assert not cam.resend_supported
        cam.start_stream(StreamConfig(frame_retention_s=0.05))
        frames = collect(cam, 15)
        stats = cam.stream.stats
    bad = [f for f in frames if not f.complete]
    assert bad and stats.resend_requests == 0
    assert sum(f.missing_packets for f in bad) >= len(bad)
    assert stats.missing_packets >= sum(f.missing_packets for f in bad)


def test_block_id_wraps_without_losses(make_fake):
    fake = make_fake(first_block_id=65530, fps=60)
    with GigECamera.open(fake.url) as cam:
        cam.start_stream()
        frames = collect(cam, 12)
        stats = cam.stream.stats
    assert [f.block_id for f in frames] == [65530, 65531, 65532, 65533, 65534, 65535, 1, 2, 3, 4, 5, 6]
    assert stats.dropped == 0 and stats.late_packets == 0 and all(f.complete for f in frames)


def test_nuc_pause_is_a_timestamp_gap_not_a_drop(make_fake):
    fake = make_fake(nuc_period_s=0.4, nuc_duration_s=0.25)
    with GigECamera.open(fake.url) as cam:
        cam.start_stream()
        frames = collect(cam, 30)
        stats = cam.stream.stats
    dts = np.diff([f.timestamp for f in frames]) / 1e9
    assert dts.max() > 0.2 and np.median(dts) == pytest.approx(1 / 30, abs=0.01)
    assert stats.dropped == 0


def test_device_clock_offset_and_drift(make_fake):
    fake = make_fake(clock_offset_s=5000.0, clock_drift_ppm=20000.0)   # exaggerated to see it in 1 s
    with GigECamera.open(fake.url) as cam:
        cam.start_stream()
        frames = collect(cam, 31)
    dev = np.array([f.timestamp for f in frames], float) / 1e9
    host = np.array([f.host_ns for f in frames], float) / 1e9
    assert dev[0] > 5000
    fit = fit_clock(dev, host)                      # host = rate * device + offset
    assert fit.rate == pytest.approx(1 / 1.02, abs=0.005)


def test_ir_format_change_applies_from_the_next_acquisition(make_fake):
    fake = make_fake()
    scene = synthetic_scene(W, H)
    with GigECamera.open(fake.url) as cam:
        a700 = flir.FlirA700(cam)
        a700.configure("TemperatureLinear10mK", W, H)
        a700.start()
        before = collect(a700, 3)
        a700.set_ir_format("TemperatureLinear100mK")
        after = collect(a700, 3)
    assert {f.meta["ir_format"] for f in before} == {"TemperatureLinear10mK"}
    assert {f.meta["ir_format"] for f in after} == {"TemperatureLinear100mK"}
    for f in before[-1:] + after[-1:]:
        t = f.timestamp / 1e9 - fake.config.clock_offset_s
        assert np.abs(a700.kelvin(f) - scene(t)).max() <= f.meta["scale_k"] / 2 + 1e-4   # quantisation, float32 scene


def test_radiometric_frames_decode_with_object_parameters(make_fake):
    fake = make_fake(ir_format="Radiometric")
    scene = synthetic_scene(W, H)
    params = flir.ObjectParameters(emissivity=0.9, reflected_k=300.0, atmospheric_k=295.0, distance_m=5.0)
    with GigECamera.open(fake.url) as cam:
        a700 = flir.FlirA700(cam)
        a700.configure("Radiometric", W, H, params=params)
        a700.start()
        f = collect(a700, 2)[-1]
    assert f.meta["ir_format"] == "Radiometric" and f.meta["scale_k"] is None
    assert f.meta["object_parameters"]["emissivity"] == pytest.approx(0.9)
    t = f.timestamp / 1e9 - fake.config.clock_offset_s
    assert np.abs(a700.kelvin(f) - scene(t)).max() < 0.1


@pytest.mark.parametrize("mtu", [1500, 4000, 9000, 1200])
def test_packet_size_is_the_largest_test_packet_that_arrives(make_fake, mtu):
    """GigE Vision test packets (SCPS fire_test_packet + do_not_fragment): the fake drops those
    above its path MTU, as a router would; the negotiated size is never above one that arrived."""
    from rig.drivers.gige.packet_size import negotiate_packet_size
    fake = make_fake(path_mtu=mtu)
    with GigECamera.open(fake.url) as cam:
        result = negotiate_packet_size(cam.device)
        assert result.tested and result.size == mtu - mtu % 4
        assert (result.size, True) in result.probes and all(not ok for s, ok in result.probes if s > result.size)
        assert cam.device.stream_packet_size() == result.size
        cam.start_stream(StreamConfig(packet_size=0))           # 0: the negotiated size
        frames = collect(cam, 3)
        assert all(f.complete for f in frames)


def test_a_camera_without_test_packets_keeps_the_default(make_fake):
    from rig.drivers.gige.packet_size import negotiate_packet_size
    fake = make_fake(test_packets=False)
    with GigECamera.open(fake.url) as cam:
        result = negotiate_packet_size(cam.device)
    assert not result.tested and result.size == 1500 and "not negotiated" in result.describe()
