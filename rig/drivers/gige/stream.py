"""GVSP reception: block reassembly, packet resend, loss accounting.

`Reassembler` is the protocol logic with time passed in (so it can be driven
by tests and fuzzers without sockets); `GvspStream` wraps it around a UDP
socket and a receiver thread.

Resend policy (after Aravis `arvgvstream.c`): a packet id is missing once a
later id of the same block has arrived (or, for the tail, once a newer block
started or the block went quiet); it is requested after
`initial_packet_timeout_s`, re-requested every `packet_timeout_s`, and a
block is given up `frame_retention_s` after its last packet. Contiguous gaps
go out as one PACKETRESEND. Blocks are delivered in arrival order, so a frame
waiting for resends holds back the ones behind it (at most the retention time).
"""
from __future__ import annotations

import collections
import logging
import os
import queue
import socket
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from rig.drivers.gige import gvcp, gvsp
from rig.drivers.gige.gvsp import Format, ImageLeader

log = logging.getLogger(__name__)

SO_RCVBUFFORCE = 33          # Linux; Python has no constant. Root may exceed net.core.rmem_max.
LATE_WINDOW = 100            # blocks at most this much older than the newest are "late"
RESYNC_JUMP = 1000           # a forward jump bigger than this is a restart, not losses


@dataclass
class StreamConfig:
    packet_size: int = 1500                 # SCPS: IP + UDP + GVSP headers + data; 0: negotiated
                                            # with test packets (rig/drivers/gige/packet_size.py)
    resend: bool = True                     # only used if the device advertises PACKETRESEND
    initial_packet_timeout_s: float = 0.002
    packet_timeout_s: float = 0.02
    frame_retention_s: float = 0.2
    max_resend_ratio: float = 0.25          # stop requesting a block beyond this share of its packets
    max_in_flight: int = 8
    socket_buffer_bytes: int = 32 << 20
    max_payload_bytes: int = 64 << 20       # leaders announcing more are malformed


@dataclass
class StreamStats:
    packets: int = 0
    bytes: int = 0
    complete: int = 0
    incomplete: int = 0
    dropped: int = 0             # blocks of which no packet arrived
    missing_packets: int = 0     # leader/data packets absent from delivered incomplete frames
    malformed: int = 0           # not GVSP, or contradicting their block
    duplicates: int = 0
    late_packets: int = 0        # for blocks already delivered or given up
    error_packets: int = 0       # GVSP packets with an error status (e.g. PACKET_UNAVAILABLE)
    resend_requests: int = 0     # PACKETRESEND commands sent
    resend_requested_packets: int = 0
    resent_packets: int = 0      # arrived flagged as resent
    resyncs: int = 0             # block-id discontinuities (acquisition restarted)
    evicted: int = 0             # blocks closed early because too many were in flight

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class Frame:
    """One delivered block. `data` is the payload as received, bytes of missing packets zero."""
    block_id: int
    timestamp: int               # device ticks from the leader (0 if the leader was lost)
    host_ns: int                 # host monotonic ns at the block's first packet
    host_done_ns: int            # host monotonic ns at delivery
    pixel_format: int
    width: int
    height: int
    data: bytes
    complete: bool
    missing_packets: int = 0
    resent_packets: int = 0
    dropped_before: int = 0      # blocks lost entirely just before this one
    has_leader: bool = True
    meta: dict = field(default_factory=dict)   # filled by device profiles (e.g. IRFormat)

    def array(self) -> np.ndarray:
        """Pixels (height, width): uint8 for 8-bit formats, little-endian uint16 otherwise."""
        dtype = np.uint8 if gvsp.bits_per_pixel(self.pixel_format) <= 8 else np.dtype("<u2")
        n = self.width * self.height
        return np.frombuffer(self.data, dtype=dtype, count=n).reshape(self.height, self.width)


class _Block:
    __slots__ = ("block_id", "size", "n_data", "data", "got", "n_data_got", "leader", "first_ns",
                 "last_ns", "highest", "missing", "requested", "resent", "give_up_resend",
                 "done", "complete", "dropped_before")

    def __init__(self, block_id: int, size: int, n_data: int, now: int, dropped_before: int):
        self.block_id = block_id
        self.size = size
        self.n_data = n_data
        self.data = bytearray(size)
        self.got = bytearray(n_data + 2)       # leader, data 1..n, trailer
        self.n_data_got = 0
        self.leader: ImageLeader | None = None
        self.first_ns = self.last_ns = now
        self.highest = -1
        self.missing: dict[int, list[int]] = {}  # packet id -> [first seen missing, last request]
        self.requested = 0
        self.resent = 0
        self.give_up_resend = False
        self.done = self.complete = False
        self.dropped_before = dropped_before


class Reassembler:
    """Turns GVSP datagrams into frames. `feed` never raises on bad input; it counts it."""

    def __init__(self, geometry: ImageLeader, config: StreamConfig,
                 deliver: Callable[[Frame], None],
                 request_resend: Callable[[int, int, int, bool], None] | None = None):
        self.geometry = geometry            # expected pixel format / width / height
        self.config = config
        self.deliver = deliver
        self.request_resend = request_resend if config.resend else None
        self.stats = StreamStats()
        self.chunk = gvsp.data_per_packet(config.packet_size)
        self._blocks: collections.OrderedDict[int, _Block] = collections.OrderedDict()
        self._recent: collections.deque[int] = collections.deque(maxlen=4 * LATE_WINDOW)
        self._recent_set: set[int] = set()
        self._last_block: int | None = None
        self._extended = False

    def reset_sequence(self) -> None:
        """Forget the block-id sequence (call before AcquisitionStart: ids restart)."""
        self._last_block = None
        self._recent.clear()
        self._recent_set.clear()

    # -- packets ----------------------------------------------------------------------------
    def feed(self, buf: memoryview, now: int) -> None:
        st = self.stats
        st.packets += 1
        st.bytes += len(buf)
        try:
            pkt = gvsp.parse_packet(buf)
        except gvsp.GvspFormatError:
            st.malformed += 1
            return
        if pkt.status & 0x8000:
            st.error_packets += 1
            blk = self._blocks.get(pkt.block_id)
            if blk is not None:                 # e.g. PACKET_UNAVAILABLE: stop asking
                blk.give_up_resend = True
            return
        leader = self._check(pkt)           # validate before a packet may open a block
        if leader is False:
            st.malformed += 1
            return
        blk = self._block_for(pkt.block_id, pkt.extended, pkt.fmt, now)
        if blk is None:
            return
        pid = pkt.packet_id
        if pid >= len(blk.got):
            st.malformed += 1
            return
        if blk.got[pid]:
            st.duplicates += 1
            return
        if not self._store(blk, pkt, pid, leader):
            st.malformed += 1
            return
        blk.got[pid] = 1
        if pkt.resent:
            blk.resent += 1
            st.resent_packets += 1
        if pid > blk.highest + 1:
            for p in range(blk.highest + 1, pid):
                if not blk.got[p] and p not in blk.missing:
                    blk.missing[p] = [now, 0]
        blk.highest = max(blk.highest, pid)
        blk.missing.pop(pid, None)
        blk.last_ns = now
        if blk.leader is not None and blk.n_data_got >= blk.n_data:
            self._finish(blk, now, complete=True)

    def _check(self, pkt: gvsp.Packet) -> ImageLeader | None | bool:
        """-> the parsed leader, None for a plausible data/trailer packet, False if malformed."""
        if pkt.fmt == Format.LEADER:
            if pkt.packet_id != 0:
                return False
            try:
                leader = gvsp.parse_leader(pkt.payload)
            except gvsp.GvspFormatError:
                return False
            ok = (leader.payload_type == gvsp.PAYLOAD_TYPE_IMAGE
                  and 0 < leader.image_size <= self.config.max_payload_bytes)
            return leader if ok else False
        if pkt.fmt not in (Format.TRAILER, Format.PAYLOAD) or pkt.packet_id == 0:
            return False
        return None

    def _store(self, blk: _Block, pkt: gvsp.Packet, pid: int, leader: ImageLeader | None) -> bool:
        fmt = pkt.fmt
        if pid == 0:
            if leader.image_size != blk.size:
                self._resize(blk, leader.image_size)
            blk.leader = leader
            return True
        if fmt == Format.TRAILER:
            if pid - 1 < blk.n_data:            # a short block: fewer data packets than expected
                blk.n_data = pid - 1
                blk.n_data_got = sum(blk.got[1:pid])
                for p in [p for p in blk.missing if p >= pid]:
                    del blk.missing[p]
            return pid == blk.n_data + 1
        if fmt != Format.PAYLOAD or pid > blk.n_data:
            return False
        off = (pid - 1) * self.chunk
        n = min(len(pkt.payload), blk.size - off)
        blk.data[off:off + n] = pkt.payload[:n]
        blk.n_data_got += 1
        return True

    def _resize(self, blk: _Block, size: int) -> None:
        n_data = -(-size // self.chunk)
        data = bytearray(size)
        keep = min(size, blk.size)
        data[:keep] = blk.data[:keep]
        got = bytearray(n_data + 2)
        keep_pids = min(len(got), len(blk.got)) - 1   # never carry a trailer flag into data
        got[:keep_pids] = blk.got[:keep_pids]
        blk.data, blk.got, blk.size, blk.n_data = data, got, size, n_data
        blk.n_data_got = sum(got[1:n_data + 1])

    def _block_for(self, block_id: int, extended: bool, fmt: int, now: int) -> _Block | None:
        blk = self._blocks.get(block_id)
        if blk is not None:
            return blk
        st = self.stats
        if block_id in self._recent_set:
            if fmt != Format.TRAILER:    # a frame is delivered before its trailer arrives
                st.late_packets += 1
            return None
        if block_id == 0:
            st.malformed += 1
            return None
        dropped = 0
        if self._last_block is not None and extended == self._extended:
            d = block_id - self._last_block if extended else gvsp.block_delta(block_id, self._last_block)
            if -LATE_WINDOW < d <= 0:
                st.late_packets += 1
                return None
            if d > RESYNC_JUMP or d <= -LATE_WINDOW:
                st.resyncs += 1
            else:
                dropped = d - 1
                st.dropped += dropped
        self._last_block, self._extended = block_id, extended
        g = self.geometry
        size = gvsp.image_size(g.pixel_format, g.width, g.height)
        blk = _Block(block_id, size, -(-size // self.chunk), now, dropped)
        self._blocks[block_id] = blk
        if len(self._blocks) > self.config.max_in_flight:
            oldest = next(b for b in self._blocks.values() if not b.done)
            self.stats.evicted += 1
            self._finish(oldest, now, complete=False)
        return blk

    # -- timers -----------------------------------------------------------------------------
    def tick(self, now: int, idle: bool = True) -> None:
        """Request resends that are due and give up blocks that went quiet. `idle`: the socket
        was found empty, so the newest block's silence is real, not packets still queued."""
        cfg = self.config
        retention = int(cfg.frame_retention_s * 1e9)
        initial = int(cfg.initial_packet_timeout_s * 1e9)
        interval = int(cfg.packet_timeout_s * 1e9)
        for blk in list(self._blocks.values()):
            if blk.done:
                continue
            newest = blk.block_id == self._last_block
            silent = now - blk.last_ns
            if (idle or not newest) and silent > retention:
                self._finish(blk, now, complete=False)
                continue
            if self.request_resend is None or blk.give_up_resend:
                continue
            # the tail is lost once a newer block started, or after a long silence (a sender
            # may pause mid-block for a few ms; then the tail is merely late)
            if blk.highest < blk.n_data and (not newest or (idle and silent > interval)):
                for p in range(blk.highest + 1, blk.n_data + 1):   # the tail never arrived
                    if not blk.got[p] and p not in blk.missing:
                        blk.missing[p] = [blk.last_ns, 0]
            due = sorted(p for p, (since, last) in blk.missing.items()
                         if now - since >= initial and now - last >= interval)
            if due:
                self._request(blk, due, now)

    def _request(self, blk: _Block, pids: list[int], now: int) -> None:
        limit = self.config.max_resend_ratio * (blk.n_data + 2)
        start = prev = pids[0]
        ranges = []
        for p in pids[1:] + [None]:
            if p is not None and p == prev + 1:
                prev = p
                continue
            ranges.append((start, prev))
            if p is not None:
                start = prev = p
        for first, last in ranges:
            if blk.requested + last - first + 1 > limit:
                blk.give_up_resend = True
                return
            self.request_resend(blk.block_id, first, last, self._extended)
            self.stats.resend_requests += 1
            self.stats.resend_requested_packets += last - first + 1
            blk.requested += last - first + 1
        for p in pids:
            blk.missing[p][1] = now

    # -- delivery ---------------------------------------------------------------------------
    def _finish(self, blk: _Block, now: int, complete: bool) -> None:
        blk.done, blk.complete = True, complete
        self._remember(blk.block_id)
        self._flush(now)

    def _remember(self, block_id: int) -> None:
        if len(self._recent) == self._recent.maxlen:
            self._recent_set.discard(self._recent[0])
        self._recent.append(block_id)
        self._recent_set.add(block_id)

    def _flush(self, now: int) -> None:
        while self._blocks:
            blk = next(iter(self._blocks.values()))
            if not blk.done:
                return
            del self._blocks[blk.block_id]
            self.deliver(self._frame(blk, now))

    def _frame(self, blk: _Block, now: int) -> Frame:
        st = self.stats
        missing = 0 if blk.complete else (blk.n_data + 1) - (blk.got[0] + blk.n_data_got)
        if blk.complete:
            st.complete += 1
        else:
            st.incomplete += 1
            st.missing_packets += missing
        ld = blk.leader or self.geometry
        return Frame(block_id=blk.block_id, timestamp=blk.leader.timestamp if blk.leader else 0,
                     host_ns=blk.first_ns, host_done_ns=now, pixel_format=ld.pixel_format,
                     width=ld.width, height=ld.height, data=bytes(blk.data), complete=blk.complete,
                     missing_packets=missing, resent_packets=blk.resent,
                     dropped_before=blk.dropped_before, has_leader=blk.leader is not None)

    def flush_all(self, now: int) -> None:
        """Give up every block still in flight (end of stream)."""
        for blk in list(self._blocks.values()):
            if not blk.done:
                blk.done = True
                self._remember(blk.block_id)
        self._flush(now)


def set_receive_buffer(sock: socket.socket, size: int) -> int:
    """Ask for a large receive buffer: a whole frame arrives as one burst. As root,
    SO_RCVBUFFORCE ignores net.core.rmem_max. Returns what the kernel granted."""
    if os.geteuid() == 0:
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
        except OSError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    else:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    if granted < size:
        log.warning("socket receive buffer is %d bytes (asked %d); raise net.core.rmem_max "
                    "or run as root, or frames will be lost in bursts", granted, size)
    return granted


class GvspStream:
    """Receive one stream channel on a UDP socket; frames come out of `get()` in block order."""

    def __init__(self, geometry: ImageLeader, device_address: str, gvcp_port: int,
                 host_ip: str = "0.0.0.0", config: StreamConfig | None = None,
                 resend_supported: bool = False, channel: int = 0):
        self.config = config or StreamConfig()
        self.device = (device_address, gvcp_port)
        self.channel = channel
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket_buffer_bytes = set_receive_buffer(self.sock, self.config.socket_buffer_bytes)
        self.sock.bind((host_ip, 0))
        self.port = self.sock.getsockname()[1]
        self.frames: queue.Queue[Frame] = queue.Queue()
        resend_config = self.config if resend_supported else StreamConfig(**{**asdict(self.config), "resend": False})
        self.reassembler = Reassembler(geometry, resend_config, self.frames.put, self._send_resend)
        self._req_id = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.cpu_s = 0.0             # CPU time of the receiver thread
        self.last_packet_ns = 0

    @property
    def stats(self) -> StreamStats:
        return self.reassembler.stats

    def reset_sequence(self) -> None:
        with self._lock:
            self.reassembler.reset_sequence()

    def _send_resend(self, block_id: int, first: int, last: int, extended: bool) -> None:
        self._req_id = gvcp.next_req_id(self._req_id)
        payload = gvcp.packetresend_payload(self.channel, block_id, first, last, extended)
        flags = gvcp.Flag.EXTENDED_IDS if extended else 0
        try:
            self.sock.sendto(gvcp.build_command(gvcp.Command.PACKETRESEND, payload, self._req_id, flags),
                             self.device)
        except OSError as exc:
            log.debug("PACKETRESEND: %s", exc)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="gvsp-receiver", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        buf = bytearray(65536)
        view = memoryview(buf)
        sock, feed, tick = self.sock, self.reassembler.feed, self.reassembler.tick
        tick_every = max(int(self.config.initial_packet_timeout_s * 1e9) // 2, 500_000)
        sock.settimeout(0.005)
        last_tick = time.monotonic_ns()
        cpu0 = time.thread_time()
        while not self._stop.is_set():
            try:
                n = sock.recv_into(buf)
            except socket.timeout:
                n = -1
            except OSError:
                if self._stop.is_set():
                    break
                continue
            now = time.monotonic_ns()
            with self._lock:
                if n >= 0:
                    self.last_packet_ns = now
                    feed(view[:n], now)
                if now - last_tick >= tick_every or n < 0:
                    tick(now, idle=n < 0)
                    last_tick = now
            self.cpu_s = time.thread_time() - cpu0
        with self._lock:
            self.reassembler.flush_all(time.monotonic_ns())

    def drain(self, quiet_s: float = 0.1, timeout_s: float = 2.0) -> None:
        """After AcquisitionStop: wait until packets stop, then deliver what is in flight."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and time.monotonic_ns() - self.last_packet_ns < quiet_s * 1e9:
            time.sleep(quiet_s / 4)
        with self._lock:
            self.reassembler.flush_all(time.monotonic_ns())

    def get(self, timeout: float | None = None) -> Frame:
        """Next frame (raises queue.Empty on timeout)."""
        return self.frames.get(timeout=timeout)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.sock.close()
