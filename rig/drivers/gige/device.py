"""GigE Vision control channel: discovery, register/memory access, privilege and heartbeat.

`GigEDevice` talks GVCP to one camera over a connected UDP socket. Every
command carries a fresh request id (1..0xFFFF); a lost command or ack is
re-sent with the *same* id; acks whose code or id do not match are stale
answers to earlier tries and are dropped; a PENDING_ACK extends the wait.
Holding the control privilege needs a heartbeat: we read the CCP register
(0x0A00) every second, which is what both real cameras and Aravis's fake
camera (which only honours that register) accept.
"""
from __future__ import annotations

import fcntl
import logging
import socket
import struct
import threading
import time
from dataclasses import dataclass

from rig.drivers.gige import gvcp
from rig.drivers.gige.gvcp import Command, Reg

log = logging.getLogger(__name__)

SIOCGIFADDR = 0x8915
SIOCGIFBRDADDR = 0x8919
SIOCGIFFLAGS = 0x8913
IFF_BROADCAST = 0x2


class GvcpError(RuntimeError):
    """The device answered a command with an error status."""

    def __init__(self, status: int, what: str):
        super().__init__(f"{what}: device answered {gvcp.status_name(status)}")
        self.status = status


class GvcpTimeout(TimeoutError):
    """No acknowledge after all retries."""


@dataclass
class ControlConfig:
    timeout_s: float = 0.5            # per try (Aravis default)
    retries: int = 5                  # extra tries, same req_id
    heartbeat_period_s: float = 1.0   # <= heartbeat timeout / 3


@dataclass
class ControlStats:
    commands: int = 0
    retries: int = 0
    pending_acks: int = 0
    stale_acks: int = 0
    malformed_acks: int = 0


class GigEDevice:
    """Control channel of one GigE Vision device (GVCP over UDP)."""

    def __init__(self, address: str, port: int = gvcp.GVCP_PORT, config: ControlConfig | None = None):
        self.address = address
        self.port = port
        self.config = config or ControlConfig()
        self.stats = ControlStats()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((address, port))
        self._lock = threading.Lock()
        self._req_id = 0
        self._heartbeat: threading.Thread | None = None
        self._stop_heartbeat = threading.Event()
        self.control_lost = threading.Event()

    # -- transactions -----------------------------------------------------------------------
    def transact(self, command: int, payload: bytes, what: str) -> bytes:
        """Send one command, wait for its ack (retrying), return the ack payload."""
        with self._lock:
            self._req_id = gvcp.next_req_id(self._req_id)
            req_id = self._req_id
            packet = gvcp.build_command(command, payload, req_id)
            self.stats.commands += 1
            for attempt in range(self.config.retries + 1):
                if attempt:
                    self.stats.retries += 1
                self.sock.send(packet)
                ack = self._wait_ack(command + 1, req_id)
                if ack is None:
                    continue
                if ack.status != gvcp.Status.SUCCESS:
                    raise GvcpError(ack.status, what)
                return ack.payload
        raise GvcpTimeout(f"{what}: no answer from {self.address}:{self.port} after "
                          f"{self.config.retries + 1} tries of {self.config.timeout_s} s")

    def _wait_ack(self, ack_code: int, req_id: int) -> gvcp.AckPacket | None:
        deadline = time.monotonic() + self.config.timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self.sock.settimeout(remaining)
            try:
                data = self.sock.recv(2048)
            except (socket.timeout, ConnectionRefusedError):
                # ICMP port unreachable surfaces as ECONNREFUSED on a connected socket
                if time.monotonic() < deadline:
                    time.sleep(min(0.01, max(0.0, deadline - time.monotonic())))
                    continue
                return None
            try:
                ack = gvcp.parse_ack(data)
            except gvcp.GvcpFormatError:
                self.stats.malformed_acks += 1
                continue
            if ack.ack_id != req_id:
                self.stats.stale_acks += 1
                continue
            if ack.ack == Command.PENDING_ACK:
                try:
                    wait_ms = gvcp.pending_ack_ms(ack.payload)
                except gvcp.GvcpFormatError:
                    self.stats.malformed_acks += 1
                    continue
                self.stats.pending_acks += 1
                deadline = time.monotonic() + wait_ms / 1000 + self.config.timeout_s
                continue
            if ack.ack != ack_code:
                self.stats.stale_acks += 1
                continue
            return ack

    # -- registers and memory ---------------------------------------------------------------
    def read_regs(self, addresses: list[int]) -> list[int]:
        """One READREG per register: devices without the concatenation capability
        (Aravis's fake among them) answer only the first of several."""
        return [self.read_reg(a) for a in addresses]

    def read_reg(self, address: int) -> int:
        payload = self.transact(Command.READREG, gvcp.readreg_payload([address]),
                                f"READREG 0x{address:X}")
        if len(payload) < 4:
            raise GvcpError(gvcp.Status.ERROR, f"READREG 0x{address:X}: short ack ({len(payload)} bytes)")
        return struct.unpack_from(">I", payload)[0]

    def write_regs(self, pairs: list[tuple[int, int]]) -> None:
        self.transact(Command.WRITEREG, gvcp.writereg_payload(pairs),
                      f"WRITEREG {[(hex(a), v) for a, v in pairs]}")

    def write_reg(self, address: int, value: int) -> None:
        self.write_regs([(address, value)])

    def read_mem(self, address: int, length: int) -> bytes:
        """Read any byte range: aligned to 4 bytes and split into <=512-byte READMEMs."""
        start = address & ~3
        end = (address + length + 3) & ~3
        out = bytearray()
        pos = start
        while pos < end:
            count = min(gvcp.MAX_PAYLOAD, end - pos)
            payload = self.transact(Command.READMEM, gvcp.readmem_payload(pos, count),
                                    f"READMEM 0x{pos:X}+{count}")
            chunk = payload[4:4 + count]
            if len(chunk) < count:
                raise GvcpError(gvcp.Status.ERROR, f"READMEM 0x{pos:X}: short ack")
            out += chunk
            pos += count
        return bytes(out[address - start:address - start + length])

    def write_mem(self, address: int, data: bytes) -> None:
        """Write any byte range; unaligned edges are read-modified-written."""
        start = address & ~3
        end = (address + len(data) + 3) & ~3
        if start != address or end != address + len(data):
            buf = bytearray(self.read_mem(start, end - start))
            buf[address - start:address - start + len(data)] = data
            data, address = bytes(buf), start
        for pos in range(0, len(data), gvcp.MAX_PAYLOAD):
            chunk = data[pos:pos + gvcp.MAX_PAYLOAD]
            # The Aravis fake puts the address in WRITEMEM's ack "index" field: don't check it.
            self.transact(Command.WRITEMEM, gvcp.writemem_payload(address + pos, chunk),
                          f"WRITEMEM 0x{address + pos:X}+{len(chunk)}")

    # -- device facts -----------------------------------------------------------------------
    def read_string(self, address: int, length: int) -> str:
        return self.read_mem(address, length).split(b"\0", 1)[0].decode("ascii", "replace")

    def capabilities(self) -> int:
        return self.read_reg(Reg.GVCP_CAPABILITY)

    def timestamp_frequency(self) -> int:
        """Device timestamp ticks per second (0 if the device has no timestamp)."""
        high, low = self.read_regs([Reg.TIMESTAMP_FREQ_HIGH, Reg.TIMESTAMP_FREQ_LOW])
        return (high << 32) | low

    def latch_timestamp(self) -> tuple[int, int]:
        """Latch the device clock. -> (device ticks, host monotonic ns at mid-request)."""
        t0 = time.monotonic_ns()
        self.write_reg(Reg.TIMESTAMP_CONTROL, gvcp.TIMESTAMP_LATCH)
        t1 = time.monotonic_ns()
        high, low = self.read_regs([Reg.TIMESTAMP_VALUE_HIGH, Reg.TIMESTAMP_VALUE_LOW])
        return (high << 32) | low, (t0 + t1) // 2

    def host_address(self) -> str:
        """Our IPv4 address on the route to the device."""
        return self.sock.getsockname()[0]

    # -- stream channel registers -----------------------------------------------------------
    def configure_stream_channel(self, host_ip: str, host_port: int, packet_size: int,
                                 channel: int = 0) -> None:
        """SCDA and SCPS first, SCP (which arms the channel) last, all before AcquisitionStart."""
        off = channel * gvcp.STREAM_CHANNEL_STRIDE
        ip = struct.unpack(">I", socket.inet_aton(host_ip))[0]
        scps = self.read_reg(Reg.SCPS0 + off)
        self.write_reg(Reg.SCDA0 + off, ip)
        self.write_reg(Reg.SCPS0 + off, (scps & ~gvcp.SCPS_SIZE_MASK) | packet_size)
        self.write_reg(Reg.SCP0 + off, host_port)

    def stream_packet_size(self, channel: int = 0) -> int:
        return self.read_reg(Reg.SCPS0 + channel * gvcp.STREAM_CHANNEL_STRIDE) & gvcp.SCPS_SIZE_MASK

    def stop_stream_channel(self, channel: int = 0) -> None:
        self.write_reg(Reg.SCP0 + channel * gvcp.STREAM_CHANNEL_STRIDE, 0)

    # -- control privilege ------------------------------------------------------------------
    def take_control(self, exclusive: bool = False) -> None:
        """Write CCP and keep it with a heartbeat thread (READREG CCP every period)."""
        self.write_reg(Reg.CCP, gvcp.CCP_EXCLUSIVE if exclusive else gvcp.CCP_CONTROL)
        self.control_lost.clear()
        self._stop_heartbeat.clear()
        self._heartbeat = threading.Thread(target=self._heartbeat_loop, name="gvcp-heartbeat",
                                           daemon=True)
        self._heartbeat.start()

    def _heartbeat_loop(self) -> None:
        while not self._stop_heartbeat.wait(self.config.heartbeat_period_s):
            try:
                ccp = self.read_reg(Reg.CCP)
            except (GvcpError, GvcpTimeout, OSError) as exc:
                log.warning("heartbeat to %s failed: %s", self.address, exc)
                self.control_lost.set()
                return
            if not ccp & (gvcp.CCP_CONTROL | gvcp.CCP_EXCLUSIVE):
                log.warning("control of %s lost (CCP=0x%X)", self.address, ccp)
                self.control_lost.set()
                return

    def release_control(self) -> None:
        self._stop_heartbeat.set()
        if self._heartbeat is not None:
            self._heartbeat.join()
            self._heartbeat = None
        if not self.control_lost.is_set():
            try:
                self.write_reg(Reg.CCP, 0)
            except (GvcpError, GvcpTimeout, OSError) as exc:
                log.warning("releasing control of %s: %s", self.address, exc)

    def close(self) -> None:
        self.release_control()
        self.sock.close()

    def __enter__(self) -> GigEDevice:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- discovery -----------------------------------------------------------------------------------

def broadcast_addresses() -> list[str]:
    """IPv4 broadcast address of every interface that has one (not loopback)."""
    out = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _, name in socket.if_nameindex():
            req = struct.pack("256s", name.encode()[:15])
            try:
                flags = struct.unpack_from("H", fcntl.ioctl(s.fileno(), SIOCGIFFLAGS, req), 16)[0]
                if not flags & IFF_BROADCAST:
                    continue
                out.append(socket.inet_ntoa(fcntl.ioctl(s.fileno(), SIOCGIFBRDADDR, req)[20:24]))
            except OSError:      # no IPv4 address on this interface
                continue
    return out


def discover(addresses: list[str] | None = None, port: int = gvcp.GVCP_PORT,
             timeout_s: float = 0.5) -> list[gvcp.DeviceInfo]:
    """Find GigE Vision devices: DISCOVERY to each address (default: every interface's
    broadcast address, 255.255.255.255 and 127.0.0.1); answers are parsed bootstrap info."""
    if addresses is None:
        addresses = broadcast_addresses() + ["255.255.255.255", "127.0.0.1"]
    packet = gvcp.build_command(Command.DISCOVERY, b"", gvcp.DISCOVERY_REQ_ID,
                                gvcp.Flag.ACK_REQUIRED | gvcp.Flag.BROADCAST_ACK)
    found: dict[tuple, gvcp.DeviceInfo] = {}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        sock.bind(("0.0.0.0", 0))
        for addr in addresses:
            try:
                sock.sendto(packet, (addr, port))
            except OSError as exc:       # e.g. no route for a broadcast address
                log.debug("discovery to %s: %s", addr, exc)
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            sock.settimeout(remaining)
            try:
                data, src = sock.recvfrom(2048)
            except socket.timeout:
                break
            except OSError:
                continue
            try:
                ack = gvcp.parse_ack(data)
                if ack.ack != Command.DISCOVERY + 1 or ack.status != gvcp.Status.SUCCESS:
                    continue
                info = gvcp.parse_discovery_ack(ack.payload, src[0], src[1])
            except gvcp.GvcpFormatError:
                continue
            # a device seen through several interfaces answers once per route: keep one,
            # preferring the address it reports as its own
            key = (info.manufacturer, info.model, info.serial, info.mac)
            if key not in found or info.address == info.ip:
                found[key] = info
    return list(found.values())
