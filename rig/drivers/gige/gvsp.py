"""GVSP (GigE Vision Streaming Protocol) packets: headers, image leader and trailer.

A block (one frame) is a leader (packet id 0), payload packets 1..N carrying
`SCPS - 36` bytes each (`SCPS - 48` with extended ids; the last one short) and a
trailer (id N+1). Headers are big-endian; Mono16 pixels are little-endian.
"""
from __future__ import annotations

import enum
import math
import struct
from typing import NamedTuple

IP_UDP_HEADERS = 28
STD_HEADER = struct.Struct(">HHI")          # status, block_id, EI|format<<24|packet_id
EXT_HEADER = struct.Struct(">HHIQI")        # status, flags, EI|format<<24, block_id, packet_id
LEADER = struct.Struct(">HHQIIIIIHH")       # reserved, payload_type, timestamp, pixfmt, w, h, ox, oy, px, py
TRAILER = struct.Struct(">HHI")             # reserved, payload_type, size_y
EI_BIT = 0x80
EXT_FLAG_RESEND = 0x0001
PAYLOAD_TYPE_IMAGE = 0x0001
PAYLOAD_TYPE_MASK = 0x3FFF                  # bit 0x4000 = extended chunk mode


class Format(enum.IntEnum):
    LEADER = 1
    TRAILER = 2
    PAYLOAD = 3
    ALL_IN = 4


PIXEL_FORMATS = {
    "Mono8": 0x01080001,
    "Mono10": 0x01100003,
    "Mono12": 0x01100005,
    "Mono14": 0x01100025,
    "Mono16": 0x01100007,
    "RGB8": 0x02180014,
}
PIXEL_FORMAT_NAMES = {v: k for k, v in PIXEL_FORMATS.items()}


def bits_per_pixel(pixel_format: int) -> int:
    """PFNC codes carry the pixel size in bits 23..16."""
    return (pixel_format >> 16) & 0xFF


def image_size(pixel_format: int, width: int, height: int) -> int:
    return width * height * bits_per_pixel(pixel_format) // 8


class GvspFormatError(ValueError):
    """A datagram that is not a well-formed GVSP packet."""


class Packet(NamedTuple):
    status: int
    block_id: int
    fmt: int
    packet_id: int
    extended: bool
    resent: bool
    payload: memoryview


def header_size(extended: bool) -> int:
    return EXT_HEADER.size if extended else STD_HEADER.size


def data_per_packet(packet_size: int, extended: bool = False) -> int:
    """Payload bytes per data packet for an SCPS packet size (which includes IP+UDP+GVSP headers)."""
    return packet_size - IP_UDP_HEADERS - header_size(extended)


def n_data_packets(payload_size: int, packet_size: int, extended: bool = False) -> int:
    return math.ceil(payload_size / data_per_packet(packet_size, extended))


def parse_packet(buf: memoryview) -> Packet:
    if len(buf) < STD_HEADER.size:
        raise GvspFormatError(f"GVSP packet of {len(buf)} bytes is shorter than its header")
    status, block16, word = STD_HEADER.unpack_from(buf)
    ei_fmt = word >> 24
    if ei_fmt & EI_BIT:
        if len(buf) < EXT_HEADER.size:
            raise GvspFormatError(f"extended GVSP packet of {len(buf)} bytes is truncated")
        status, flags, word, block_id, packet_id = EXT_HEADER.unpack_from(buf)
        fmt = (word >> 24) & 0x7F
        return Packet(status, block_id, fmt, packet_id, True,
                      bool(flags & EXT_FLAG_RESEND) or status == 0x0100, buf[EXT_HEADER.size:])
    return Packet(status, block16, ei_fmt & 0x7F, word & 0xFFFFFF, False,
                  status == 0x0100, buf[STD_HEADER.size:])


def build_packet(status: int, block_id: int, fmt: int, packet_id: int, payload: bytes,
                 extended: bool = False, resent_flag: bool = False) -> bytes:
    if extended:
        flags = EXT_FLAG_RESEND if resent_flag else 0
        return EXT_HEADER.pack(status, flags, (EI_BIT | fmt) << 24, block_id, packet_id) + payload
    return STD_HEADER.pack(status, block_id & 0xFFFF, (fmt << 24) | (packet_id & 0xFFFFFF)) + payload


class ImageLeader(NamedTuple):
    payload_type: int
    timestamp: int        # device ticks
    pixel_format: int
    width: int
    height: int
    offset_x: int = 0
    offset_y: int = 0
    padding_x: int = 0
    padding_y: int = 0

    @property
    def image_size(self) -> int:
        return image_size(self.pixel_format, self.width, self.height) + self.padding_y


def parse_leader(payload: memoryview) -> ImageLeader:
    if len(payload) < LEADER.size:
        raise GvspFormatError(f"leader payload of {len(payload)} bytes, expected {LEADER.size}")
    _, ptype, ts, pixfmt, w, h, ox, oy, px, py = LEADER.unpack_from(payload)
    return ImageLeader(ptype & PAYLOAD_TYPE_MASK, ts, pixfmt, w, h, ox, oy, px, py)


def build_leader(leader: ImageLeader) -> bytes:
    return LEADER.pack(0, leader.payload_type, leader.timestamp, leader.pixel_format, leader.width,
                       leader.height, leader.offset_x, leader.offset_y, leader.padding_x,
                       leader.padding_y)


def build_trailer(payload_type: int, size_y: int) -> bytes:
    return TRAILER.pack(0, payload_type, size_y)


def block_delta(new: int, last: int) -> int:
    """Signed distance between 16-bit block ids, which skip 0 when wrapping 65535 -> 1."""
    d = (new - last + 0x8000) % 0x10000 - 0x8000
    if d > 0 and new < last:       # crossed the wrap forward: 0 is not a block id
        d -= 1
    elif d < 0 and new > last:     # crossed it backwards
        d += 1
    return d


def next_block_id(block_id: int) -> int:
    return block_id % 0xFFFF + 1
