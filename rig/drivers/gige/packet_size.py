"""The largest stream packet size the path from camera to host carries, found with GigE Vision test
packets (as Aravis's automatic packet size does): SCPS written with fire_test_packet (bit 31) and
do_not_fragment (bit 30) makes the camera send one UDP datagram of exactly that IP size with IP's
don't-fragment flag, so a size above the path MTU never arrives. A binary search over sizes that
arrive picks the packet size; it is never above a size that was seen to arrive.

A camera that fires no test packet at all (Aravis's fake camera, some firmware) keeps the size
asked for (1500, Ethernet's MTU, by default), and the result says so."""
from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass

from rig.drivers.gige import gvcp
from rig.drivers.gige.device import GigEDevice
from rig.drivers.gige.gvcp import Reg

IP_UDP_BYTES = 28                  # a test packet of IP size S carries S - 28 bytes of UDP payload
SCPS_FIRE_TEST = 0x80000000
SCPS_DO_NOT_FRAGMENT = 0x40000000
MIN_SIZE, MAX_SIZE = 576, 9000     # IPv4's guaranteed datagram; a 9000-byte jumbo frame


@dataclass
class PacketSizeResult:
    size: int                      # the packet size to stream with
    tested: bool                   # False: the camera fired no test packet (size = the fallback)
    probes: list[tuple[int, bool]] # (size, arrived) in the order tried

    def describe(self) -> str:
        if not self.tested:
            return f"packet size {self.size} (the camera answers no test packet: not negotiated)"
        return f"packet size {self.size} (largest test packet that arrived, {len(self.probes)} probes)"


def arrives(device: GigEDevice, sock: socket.socket, size: int, wait_s: float, channel: int = 0) -> bool:
    """Fire one test packet of IP size `size`; True if a datagram of exactly that size arrives."""
    off = channel * gvcp.STREAM_CHANNEL_STRIDE
    sock.setblocking(False)
    while True:                                   # drain what earlier probes left behind
        try:
            sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            break
    device.write_reg(Reg.SCPS0 + off, SCPS_FIRE_TEST | SCPS_DO_NOT_FRAGMENT | size)
    deadline = time.monotonic() + wait_s
    while (left := deadline - time.monotonic()) > 0:
        sock.settimeout(left)
        try:
            data, _ = sock.recvfrom(65535)
        except (socket.timeout, BlockingIOError):
            return False
        if len(data) == size - IP_UDP_BYTES:
            return True
    return False


def negotiate_packet_size(device: GigEDevice, lo: int = MIN_SIZE, hi: int = MAX_SIZE, fallback: int = 1500,
                          wait_s: float = 0.1, channel: int = 0) -> PacketSizeResult:
    """Point the stream channel at a probe socket, then binary-search the largest size (multiple of
    4) whose test packet arrives. Leaves SCPS at the result (without the test bit) and SCP at 0."""
    off = channel * gvcp.STREAM_CHANNEL_STRIDE
    probes: list[tuple[int, bool]] = []
    host_ip = device.host_address()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((host_ip, 0))
        device.write_reg(Reg.SCDA0 + off, struct.unpack(">I", socket.inet_aton(host_ip))[0])
        device.write_reg(Reg.SCP0 + off, sock.getsockname()[1])
        try:
            def probe(size: int) -> bool:
                ok = arrives(device, sock, size, wait_s, channel)
                probes.append((size, ok))
                return ok

            lo, hi = lo - lo % 4, hi - hi % 4
            if not probe(lo):
                result = PacketSizeResult(fallback, False, probes)
            elif probe(hi):
                result = PacketSizeResult(hi, True, probes)
            else:                                  # lo arrives, hi does not
                while hi - lo > 4:
                    mid = (lo + hi) // 2
                    mid -= mid % 4
                    if probe(mid):
                        lo = mid
                    else:
                        hi = mid
                result = PacketSizeResult(lo, True, probes)
        finally:
            device.write_reg(Reg.SCP0 + off, 0)
    scps = device.read_reg(Reg.SCPS0 + off)
    device.write_reg(Reg.SCPS0 + off, (scps & ~(gvcp.SCPS_SIZE_MASK | SCPS_FIRE_TEST)) | result.size)
    return result
