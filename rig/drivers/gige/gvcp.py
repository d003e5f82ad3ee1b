"""GVCP (GigE Vision Control Protocol) packets: codes, builders and parsers.

All multi-byte fields are big-endian. A command is `0x42 | flags | command |
length | req_id` followed by `length` payload bytes; an acknowledge is
`status | ack code | length | ack_id` (its first two bytes are a status, not
the 0x42 key). Both directions live here because the project's fake camera
(`tests/fakes/fake_gige.py`) speaks the device side with the same layouts,
and Aravis's fake camera checks the host side.
"""
from __future__ import annotations

import enum
import re
import struct
from dataclasses import dataclass

GVCP_PORT = 3956
KEY = 0x42
HEADER = struct.Struct(">BBHHH")   # key, flags, command, length, req_id
ACK_HEADER = struct.Struct(">HHHH")  # status, acknowledge, length, ack_id
MAX_PAYLOAD = 512                  # READMEM/WRITEMEM chunk size every device accepts
DISCOVERY_REQ_ID = 0xFFFF
BOOTSTRAP_INFO_SIZE = 0xF8         # discovery ack payload = bootstrap 0x0000..0x00F7


class Flag(enum.IntFlag):
    ACK_REQUIRED = 0x01
    BROADCAST_ACK = 0x10       # DISCOVERY / FORCEIP
    EXTENDED_IDS = 0x10        # PACKETRESEND / EVENT (same bit, other commands)


class Command(enum.IntEnum):
    DISCOVERY = 0x0002
    FORCEIP = 0x0004
    PACKETRESEND = 0x0040
    READREG = 0x0080
    WRITEREG = 0x0082
    READMEM = 0x0084
    WRITEMEM = 0x0086
    PENDING_ACK = 0x0089
    EVENT = 0x00C0
    EVENTDATA = 0x00C2
    ACTION = 0x0100


class Status(enum.IntEnum):
    """GVCP ack status, also the GVSP packet status."""
    SUCCESS = 0x0000
    PACKET_RESEND = 0x0100
    NOT_IMPLEMENTED = 0x8001
    INVALID_PARAMETER = 0x8002
    INVALID_ADDRESS = 0x8003
    WRITE_PROTECT = 0x8004
    BAD_ALIGNMENT = 0x8005
    ACCESS_DENIED = 0x8006
    BUSY = 0x8007
    PACKET_UNAVAILABLE = 0x800C
    DATA_OVERRUN = 0x800D
    INVALID_HEADER = 0x800E
    PACKET_NOT_YET_AVAILABLE = 0x8010
    PACKET_AND_PREV_REMOVED_FROM_MEMORY = 0x8011
    PACKET_REMOVED_FROM_MEMORY = 0x8012
    ERROR = 0x8FFF


def status_name(code: int) -> str:
    try:
        return Status(code).name
    except ValueError:
        return f"0x{code:04X}"


class Reg(enum.IntEnum):
    """Bootstrap registers (GigE Vision 2.x), u32 big-endian."""
    VERSION = 0x0000
    DEVICE_MODE = 0x0004
    MAC_HIGH = 0x0008
    MAC_LOW = 0x000C
    FIRST_URL = 0x0200
    SECOND_URL = 0x0400
    N_STREAM_CHANNELS = 0x0904
    GVCP_CAPABILITY = 0x0934
    HEARTBEAT_TIMEOUT = 0x0938
    TIMESTAMP_FREQ_HIGH = 0x093C
    TIMESTAMP_FREQ_LOW = 0x0940
    TIMESTAMP_CONTROL = 0x0944
    TIMESTAMP_VALUE_HIGH = 0x0948
    TIMESTAMP_VALUE_LOW = 0x094C
    CCP = 0x0A00
    SCP0 = 0x0D00             # host port (low 16 bits); 0 stops the channel
    SCPS0 = 0x0D04            # packet size (low 16 bits) incl. IP+UDP+GVSP headers
    SCPD0 = 0x0D08            # inter-packet delay (ticks)
    SCDA0 = 0x0D18            # destination IPv4


URL_SIZE = 512
STREAM_CHANNEL_STRIDE = 0x40
CAP_PACKETRESEND = 0x4
CAP_PENDING_ACK = 0x20
CCP_EXCLUSIVE = 0x1
CCP_CONTROL = 0x2
TIMESTAMP_LATCH = 0x2
SCPS_SIZE_MASK = 0xFFFF       # GenICam MSB-first "LSB 31 MSB 16" = the low 16 bits


class GvcpFormatError(ValueError):
    """A datagram that is not a well-formed GVCP packet."""


@dataclass(frozen=True)
class CommandPacket:
    flags: int
    command: int
    req_id: int
    payload: bytes


@dataclass(frozen=True)
class AckPacket:
    status: int
    ack: int
    ack_id: int
    payload: bytes


def build_command(command: int, payload: bytes, req_id: int,
                  flags: int = Flag.ACK_REQUIRED) -> bytes:
    return HEADER.pack(KEY, flags, command, len(payload), req_id) + payload


def parse_command(data: bytes) -> CommandPacket:
    if len(data) < HEADER.size:
        raise GvcpFormatError(f"command of {len(data)} bytes is shorter than its header")
    key, flags, command, length, req_id = HEADER.unpack_from(data)
    if key != KEY:
        raise GvcpFormatError(f"bad key 0x{key:02X}")
    if len(data) < HEADER.size + length:
        raise GvcpFormatError(f"truncated command: length {length}, got {len(data) - HEADER.size}")
    return CommandPacket(flags, command, req_id, bytes(data[HEADER.size:HEADER.size + length]))


def build_ack(status: int, ack: int, ack_id: int, payload: bytes = b"") -> bytes:
    return ACK_HEADER.pack(status, ack, len(payload), ack_id) + payload


def parse_ack(data: bytes) -> AckPacket:
    if len(data) < ACK_HEADER.size:
        raise GvcpFormatError(f"ack of {len(data)} bytes is shorter than its header")
    status, ack, length, ack_id = ACK_HEADER.unpack_from(data)
    if len(data) < ACK_HEADER.size + length:
        raise GvcpFormatError(f"truncated ack: length {length}, got {len(data) - ACK_HEADER.size}")
    return AckPacket(status, ack, ack_id, bytes(data[ACK_HEADER.size:ACK_HEADER.size + length]))


def next_req_id(req_id: int) -> int:
    """Request ids run 1..0xFFFF; 0 is invalid."""
    return req_id % 0xFFFF + 1


# -- payloads ---------------------------------------------------------------------------------

def readreg_payload(addresses: list[int]) -> bytes:
    return b"".join(struct.pack(">I", a) for a in addresses)


def writereg_payload(pairs: list[tuple[int, int]]) -> bytes:
    return b"".join(struct.pack(">II", a, v & 0xFFFFFFFF) for a, v in pairs)


def readmem_payload(address: int, count: int) -> bytes:
    return struct.pack(">IHH", address, 0, count)


def writemem_payload(address: int, data: bytes) -> bytes:
    return struct.pack(">I", address) + data


def pending_ack_ms(payload: bytes) -> int:
    """Time to completion announced by a PENDING_ACK (ms)."""
    if len(payload) < 4:
        raise GvcpFormatError("PENDING_ACK payload shorter than 4 bytes")
    return struct.unpack_from(">HH", payload)[1]


def packetresend_payload(channel: int, block_id: int, first_packet: int, last_packet: int,
                         extended: bool = False) -> bytes:
    """Standard ids: block id 16 bits, packet ids 24 bits; extended: u64 block id."""
    if extended:
        return struct.pack(">HHIIQ", channel, 0, first_packet, last_packet, block_id)
    return struct.pack(">HHII", channel, block_id & 0xFFFF,
                       first_packet & 0xFFFFFF, last_packet & 0xFFFFFF)


def parse_packetresend(payload: bytes, extended: bool) -> tuple[int, int, int, int]:
    """-> (channel, block_id, first_packet, last_packet)."""
    if extended:
        if len(payload) < 20:
            raise GvcpFormatError("extended PACKETRESEND payload shorter than 20 bytes")
        channel, _, first, last, block = struct.unpack_from(">HHIIQ", payload)
        return channel, block, first, last
    if len(payload) < 12:
        raise GvcpFormatError("PACKETRESEND payload shorter than 12 bytes")
    channel, block, first, last = struct.unpack_from(">HHII", payload)
    return channel, block, first & 0xFFFFFF, last & 0xFFFFFF


# -- discovery / bootstrap strings -------------------------------------------------------------

def _cstr(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", "replace").strip()


@dataclass(frozen=True)
class DeviceInfo:
    """What a DISCOVERY ack says about a device (= bootstrap memory 0x0000..0x00F7)."""
    address: str          # where the ack came from (host side view)
    port: int
    version: tuple[int, int]
    mac: str
    ip: str
    manufacturer: str
    model: str
    device_version: str
    manufacturer_info: str
    serial: str
    user_name: str

    @property
    def url(self) -> str:
        return f"gige://{self.address}" + ("" if self.port == GVCP_PORT else f":{self.port}")


def parse_discovery_ack(payload: bytes, address: str, port: int) -> DeviceInfo:
    if len(payload) < BOOTSTRAP_INFO_SIZE:
        raise GvcpFormatError(f"discovery ack payload of {len(payload)} bytes, expected {BOOTSTRAP_INFO_SIZE}")
    major, minor = struct.unpack_from(">HH", payload, 0)
    mac = payload[10:16]
    ip = ".".join(str(b) for b in payload[36:40])
    return DeviceInfo(
        address=address, port=port, version=(major, minor),
        mac=":".join(f"{b:02x}" for b in mac), ip=ip,
        manufacturer=_cstr(payload[0x48:0x68]), model=_cstr(payload[0x68:0x88]),
        device_version=_cstr(payload[0x88:0xA8]), manufacturer_info=_cstr(payload[0xA8:0xD8]),
        serial=_cstr(payload[0xD8:0xE8]), user_name=_cstr(payload[0xE8:0xF8]))


# -- GenICam XML location ----------------------------------------------------------------------

@dataclass(frozen=True)
class GenicamUrl:
    scheme: str           # "local", "file" or "http"
    name: str             # file name (local) or path/url
    address: int = 0
    length: int = 0

    @property
    def zipped(self) -> bool:
        return self.name.lower().endswith(".zip")


_LOCAL = re.compile(r"^local:\s*(?:///)?\s*([^;]+?)\s*;\s*(?:0x)?([0-9a-f]+)\s*;\s*(?:0x)?([0-9a-f]+)",
                    re.IGNORECASE)


def parse_genicam_url(url: str) -> GenicamUrl:
    """Parse the first-URL register: `Local:name;hexaddr;hexlen[?SchemaVersion=..]`,
    `File:///path` or `http://...` (hex with or without 0x, spaces tolerated)."""
    text = url.strip().split("?", 1)[0]
    m = _LOCAL.match(text)
    if m:
        return GenicamUrl("local", m.group(1), int(m.group(2), 16), int(m.group(3), 16))
    low = text.lower()
    if low.startswith("file:"):
        path = text[5:]
        return GenicamUrl("file", path[2:] if path.startswith("///") else path)
    if low.startswith(("http://", "https://")):
        return GenicamUrl("http", text)
    raise GvcpFormatError(f"unrecognised GenICam URL {url!r}")
