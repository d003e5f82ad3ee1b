"""Sync box line protocol over a pty pair, exactly as over /dev/ttyACM0."""
import time

import pytest

from rig.drivers.syncbox import SyncBox, SyncBoxError, list_serial_ports
from tests.fakes.fake_syncbox import FakeSyncBox


@pytest.fixture
def fake():
    box = FakeSyncBox(clock_offset_s=777.0, drift_ppm=200.0)
    yield box
    box.close()


def test_identity_clock_and_markers(fake):
    box = SyncBox(fake.port)
    try:
        assert box.identity == "SYNCBOX 1.0 SB0001"
        for _ in range(8):
            box.ping()
            time.sleep(0.01)
        host_now = time.monotonic()
        assert box.box_to_host_s(fake.box_us(host_now)) == pytest.approx(host_now, abs=0.002)
        box.start(period_s=0.1, on_s=0.03)
        time.sleep(0.45)
        box.stop()
        markers = []
        while not box.markers.empty():
            markers.append(box.markers.get())
        assert len(markers) >= 6 and [m.n for m in markers] == list(range(1, len(markers) + 1))
        assert [m.state for m in markers[:4]] == [1, 0, 1, 0]
        for m, (state, t_true) in zip(markers, fake.switches):
            assert m.state == state
            assert box.box_to_host_s(m.box_us) == pytest.approx(t_true, abs=0.002)
            assert m.host_ns / 1e9 >= t_true                 # arrival is never before the switch
    finally:
        box.close()


def test_errors_are_clear(fake):
    box = SyncBox(fake.port, timeout_s=0.3)
    try:
        with pytest.raises(SyncBoxError, match="ERR unknown command"):
            box.command("BOGUS")
        with pytest.raises(SyncBoxError, match="Could not exclusively lock|busy|lock"):
            SyncBox(fake.port)                               # a second user of the port
    finally:
        box.close()
    with pytest.raises(SyncBoxError, match="/dev/nonexistent"):
        SyncBox("/dev/nonexistent")


def test_list_serial_ports_shape():
    for p in list_serial_ports():
        assert set(p) >= {"port", "vid", "pid", "likely_syncbox"}
