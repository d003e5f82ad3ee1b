"""Property-based fuzzing: malformed or truncated GVCP/GVSP datagrams never raise out of
the receivers, are counted, and do not spoil good frames."""
import socket
import struct
import threading

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from rig.drivers.gige import gvcp, gvsp
from rig.drivers.gige.device import ControlConfig, GigEDevice
from rig.drivers.gige.stream import Reassembler, StreamConfig

W, H = 64, 32
GEOMETRY = gvsp.ImageLeader(gvsp.PAYLOAD_TYPE_IMAGE, 0, gvsp.PIXEL_FORMATS["Mono16"], W, H)
PACKET_SIZE = 36 + 1000


def frame_packets(block_id: int, payload: bytes) -> list[bytes]:
    chunk = gvsp.data_per_packet(PACKET_SIZE)
    n = -(-len(payload) // chunk)
    out = [gvsp.build_packet(0, block_id, gvsp.Format.LEADER, 0,
                             gvsp.build_leader(GEOMETRY._replace(timestamp=block_id * 1000)))]
    out += [gvsp.build_packet(0, block_id, gvsp.Format.PAYLOAD, i + 1, payload[i * chunk:(i + 1) * chunk])
            for i in range(n)]
    out.append(gvsp.build_packet(0, block_id, gvsp.Format.TRAILER, n + 1, gvsp.build_trailer(1, H)))
    return out


def new_reassembler(frames: list):
    return Reassembler(GEOMETRY, StreamConfig(packet_size=PACKET_SIZE, resend=False), frames.append)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=30))
def test_random_datagrams_never_raise_and_are_counted(datagrams):
    frames = []
    r = new_reassembler(frames)
    for i, d in enumerate(datagrams):
        r.feed(memoryview(d), now=i * 1000)
        r.tick(now=i * 1000)
    r.flush_all(now=10**12)
    s = r.stats
    assert s.packets == len(datagrams)
    assert s.malformed >= sum(len(d) < 8 for d in datagrams)
    assert s.complete + s.incomplete == len(frames)


def truncations(packets: list[bytes]):
    """Garbage derived from real packets: cut anywhere inside the header or the leader body,
    or bytes flipped in the format field to an unknown content type."""
    cut = st.builds(lambda i, n: packets[i % len(packets)][:n % 8],
                    st.integers(0, 10**6), st.integers(0, 10**6))
    short_leader = st.builds(lambda n: packets[0][:8 + n % gvsp.LEADER.size], st.integers(0, 10**6))
    bad_format = st.builds(lambda i, fmt: packets[i % len(packets)][:4] + bytes([fmt]) + packets[i % len(packets)][5:],
                           st.integers(0, 10**6), st.sampled_from([0, 5, 6, 7, 8, 0x7F]))
    return st.one_of(cut, short_leader, bad_format)


GOOD = [frame_packets(b, bytes(range(256)) * (2 * W * H // 256)) for b in (1, 2, 3)]


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_garbage_between_good_packets_is_counted_and_harmless(data):
    good = [p for f in GOOD for p in f]
    garbage = data.draw(st.lists(truncations(good), max_size=40))
    positions = data.draw(st.lists(st.integers(0, len(good)), min_size=len(garbage), max_size=len(garbage)))
    stream = list(good)
    for pos, g in sorted(zip(positions, garbage), key=lambda x: -x[0]):
        stream.insert(pos, g)
    frames = []
    r = new_reassembler(frames)
    for i, d in enumerate(stream):
        r.feed(memoryview(d), now=i)
    r.flush_all(now=10**9)
    assert [f.block_id for f in frames] == [1, 2, 3] and all(f.complete for f in frames)
    assert all(f.data == bytes(range(256)) * (2 * W * H // 256) for f in frames)
    s = r.stats
    assert s.malformed == len(garbage) and s.duplicates == 0 and s.late_packets == 0
    assert s.packets == len(stream)


class GarbageDevice:
    """A UDP peer that answers each GVCP command with some garbage datagrams, then the real ack."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.garbage: list[bytes] = []
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        while True:
            try:
                data, src = self.sock.recvfrom(2048)
            except OSError:
                return
            cmd = gvcp.parse_command(data)
            for g in self.garbage:
                self.sock.sendto(g, src)
            self.sock.sendto(gvcp.build_ack(0, cmd.command + 1, cmd.req_id, struct.pack(">I", 0xCAFE)), src)


DEVICE = None


def garbage_device() -> GarbageDevice:
    global DEVICE
    if DEVICE is None:
        DEVICE = GarbageDevice()
    return DEVICE


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=40),
                          st.builds(lambda st_, code, rid, body: gvcp.build_ack(st_, code, rid, body)[:len(body) + 8 - (rid % 3)],
                                    st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF),
                                    st.binary(max_size=12))),
                max_size=8))
def test_gvcp_client_survives_garbage_acks(garbage):
    dev_peer = garbage_device()
    with GigEDevice("127.0.0.1", dev_peer.port, ControlConfig(timeout_s=0.5, retries=0)) as dev:
        req_id = gvcp.next_req_id(dev._req_id)
        for g in garbage:       # a datagram that happens to be the exact ack would be no garbage
            try:
                a = gvcp.parse_ack(g)
                assume(not (a.ack_id == req_id and a.ack in (0x0081, 0x0089)))
            except gvcp.GvcpFormatError:
                pass
        dev_peer.garbage = garbage
        assert dev.read_reg(0x1234) == 0xCAFE
        s = dev.stats
        assert s.malformed_acks + s.stale_acks == len(garbage) and s.retries == 0
