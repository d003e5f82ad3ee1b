"""GVCP/GVSP byte layouts against bytes captured from Aravis's fake camera and Aravis's URL vectors."""
import struct

import pytest

from rig.drivers.gige import gvcp, gvsp
from rig.drivers.gige.camera import parse_camera_url


def test_command_header_and_req_id_wrap():
    pkt = gvcp.build_command(gvcp.Command.READREG, gvcp.readreg_payload([0x0A00]), req_id=7)
    assert pkt == bytes.fromhex("42 01 0080 0004 0007 00000A00")
    cmd = gvcp.parse_command(pkt)
    assert (cmd.command, cmd.req_id, cmd.payload) == (0x0080, 7, bytes.fromhex("00000A00"))
    assert gvcp.next_req_id(0xFFFF) == 1 and gvcp.next_req_id(1) == 2


def test_ack_status_is_16_bits_not_key():
    ack = gvcp.parse_ack(bytes.fromhex("8006 0083 0004 0009 0000 0000"))
    assert (ack.status, ack.ack, ack.ack_id) == (gvcp.Status.ACCESS_DENIED, 0x0083, 9)
    assert gvcp.status_name(ack.status) == "ACCESS_DENIED"
    with pytest.raises(gvcp.GvcpFormatError):
        gvcp.parse_ack(bytes.fromhex("0000 0081 0008 0009 0000"))   # claims 8, carries 2


def test_packetresend_layouts():
    std = gvcp.packetresend_payload(0, 0x02DC, 5, 9)
    assert std == bytes.fromhex("0000 02DC 00000005 00000009")
    assert gvcp.parse_packetresend(std, extended=False) == (0, 0x02DC, 5, 9)
    ext = gvcp.packetresend_payload(0, 1 << 40, 5, 9, extended=True)
    assert len(ext) == 20 and gvcp.parse_packetresend(ext, extended=True) == (0, 1 << 40, 5, 9)


@pytest.mark.parametrize("url,expected", [
    # vectors from Aravis tests/genicam.c and the Aravis fake camera
    ("Local:arv-fake-camera.xml;10000;3e67", ("local", "arv-fake-camera.xml", 0x10000, 0x3E67)),
    ("Local:Basler_Ace_GigE_e7c9b87e_Version_3_3.zip;c0000000;10cca",
     ("local", "Basler_Ace_GigE_e7c9b87e_Version_3_3.zip", 0xC0000000, 0x10CCA)),
    ("local:C4_2040_GigE_1.0.0.zip;0x8C400904;0x4D30", ("local", "C4_2040_GigE_1.0.0.zip", 0x8C400904, 0x4D30)),
    ("Local: guide_gige_test.zip; 00010000; 06c5", ("local", "guide_gige_test.zip", 0x10000, 0x6C5)),
    ("Local:///x.xml;100;20?SchemaVersion=1.1.0", ("local", "x.xml", 0x100, 0x20)),
    ("File:///tmp/cam.xml?SchemaVersion=1.0.0", ("file", "/tmp/cam.xml", 0, 0)),
])
def test_genicam_url_forms(url, expected):
    u = gvcp.parse_genicam_url(url)
    assert (u.scheme, u.name, u.address, u.length) == expected
    assert u.zipped == expected[1].endswith(".zip")


def test_genicam_url_rejects_garbage():
    with pytest.raises(gvcp.GvcpFormatError):
        gvcp.parse_genicam_url("Remote:foo")


def test_leader_and_trailer_bytes_captured_from_aravis_fake():
    leader = bytes.fromhex("0000 02dc 01000000" "0000 0001 18ea4017f7508de8 01100007 00000280 000001e0"
                           "00000000 00000000 0000 0000")
    pkt = gvsp.parse_packet(memoryview(leader))
    assert (pkt.status, pkt.block_id, pkt.fmt, pkt.packet_id, pkt.extended) == (0, 0x2DC, 1, 0, False)
    ld = gvsp.parse_leader(pkt.payload)
    assert (ld.width, ld.height, ld.pixel_format, ld.timestamp) == (640, 480, 0x01100007, 0x18EA4017F7508DE8)
    assert ld.image_size == 614400
    trailer = gvsp.parse_packet(memoryview(bytes.fromhex("0000 02dc 020001c4 0000 0001 00000000")))
    assert (trailer.fmt, trailer.packet_id) == (gvsp.Format.TRAILER, 452)
    # 614400 bytes at SCPS 1400: 451 data packets, trailer id 452 (as captured)
    assert gvsp.n_data_packets(614400, 1400) == 451
    assert gvsp.build_leader(ld) == leader[8:]


def test_extended_ids_header():
    raw = gvsp.build_packet(0, 1 << 33, gvsp.Format.PAYLOAD, 70000, b"xy", extended=True, resent_flag=True)
    pkt = gvsp.parse_packet(memoryview(raw))
    assert (pkt.block_id, pkt.packet_id, pkt.extended, pkt.resent, bytes(pkt.payload)) == (1 << 33, 70000, True, True, b"xy")
    assert gvsp.data_per_packet(1500, extended=True) == 1500 - 48


@pytest.mark.parametrize("new,last,delta", [(2, 1, 1), (1, 65535, 1), (2, 65535, 2), (65535, 1, -1),
                                            (65400, 65535, -135), (10, 65530, 15), (5, 5, 0)])
def test_block_delta_skips_zero_on_wrap(new, last, delta):
    assert gvsp.block_delta(new, last) == delta


def test_discovery_ack_payload():
    mem = bytearray(gvcp.BOOTSTRAP_INFO_SIZE)
    struct.pack_into(">HH", mem, 0, 2, 1)
    mem[10:16] = bytes([0, 0x40, 0x7F, 1, 2, 3])
    mem[36:40] = bytes([10, 0, 0, 7])
    mem[0x48:0x48 + 4] = b"FLIR"
    mem[0x68:0x68 + 4] = b"A700"
    mem[0xD8:0xD8 + 5] = b"12345"
    info = gvcp.parse_discovery_ack(bytes(mem), "10.0.0.7", 3956)
    assert (info.version, info.mac, info.ip, info.manufacturer, info.model, info.serial) == \
        ((2, 1), "00:40:7f:01:02:03", "10.0.0.7", "FLIR", "A700", "12345")
    assert info.url == "gige://10.0.0.7"


def test_camera_url():
    assert parse_camera_url("gige://10.0.0.7") == ("10.0.0.7", 3956)
    assert parse_camera_url("127.0.0.1:4000") == ("127.0.0.1", 4000)
    with pytest.raises(ValueError, match="gige://"):
        parse_camera_url("usb://x")
