"""A fake FLIR A700 on UDP loopback: GVCP device side + GVSP sender.

What Aravis's fake camera cannot do, this one does: PACKETRESEND (standard
ids), ACCESS_DENIED for a second controller, PENDING_ACK (on NUCAction), a
zipped GenICam XML, IRFormat behaviour (latched at AcquisitionStart), NUC
pauses, a device clock with offset and drift, and injectable GVSP packet loss,
reordering and duplication. Frames come from `source(time_s) -> kelvin (H, W)`.

    cam = FakeGigECamera(FakeConfig(loss=0.01)).start()
    ... GigECamera.open(cam.url) ...
    cam.stop()

Run standalone (for benchmarks, so the sender has its own interpreter):
    python -m tests.fakes.fake_gige --loss 0.01   # prints "gige://127.0.0.1:PORT"
"""
from __future__ import annotations

import argparse
import collections
import io
import json
import math
import random
import socket
import struct
import sys
import threading
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from rig.drivers import flir
from rig.drivers.gige import gvcp, gvsp
from rig.drivers.gige.gvcp import Command, Reg, Status

XML_PATH = Path(__file__).with_name("flir_a700_fake.xml")
XML_ADDRESS = 0x100000
MEM_SIZE = 0x110000
DEV = 0x20000                      # device registers, as laid out in flir_a700_fake.xml
REG = {"Width": DEV, "Height": DEV + 0x04, "SensorWidth": DEV + 0x08, "SensorHeight": DEV + 0x0C,
       "PixelFormat": DEV + 0x10, "AcquisitionCommand": DEV + 0x14, "AcquisitionMode": DEV + 0x18,
       "IRFormat": DEV + 0x1C, "FramePeriod": DEV + 0x20, "NUCAction": DEV + 0x24, "NUCMode": DEV + 0x28}
OBJECT_REG = {name: DEV + 0x100 + 4 * i for i, name in enumerate(flir.OBJECT_FEATURES)}
CAL_REG = {name: DEV + 0x200 + 4 * i
           for i, name in enumerate(("R", "B", "F", "X", "alpha1", "alpha2", "beta1", "beta2", "J1", "J0"))}
REG["TemperatureLinearResolution"] = DEV + 0x2C   # the "ax5" variant's (TemperatureLinearMode reuses IRFormat's)
REG["PtpEnable"], REG["PtpStatus"] = DEV + 0x30, DEV + 0x34     # with FakeConfig(ptp=...)
PTP_STATUS = {"Disabled": 0, "Listening": 1, "Master": 2, "Slave": 3}
PTP_XML = f"""  <IntReg Name="PtpEnableReg">
    <Address>{DEV + 0x30:#x}</Address><Length>4</Length><AccessMode>RW</AccessMode>
    <pPort>Device</pPort><Sign>Unsigned</Sign><Endianess>BigEndian</Endianess>
  </IntReg>
  <Boolean Name="PtpEnable"><pValue>PtpEnableReg</pValue><OnValue>1</OnValue><OffValue>0</OffValue></Boolean>
  <IntReg Name="PtpStatusReg">
    <Address>{DEV + 0x34:#x}</Address><Length>4</Length><AccessMode>RO</AccessMode>
    <pPort>Device</pPort><Cachable>NoCache</Cachable><Sign>Unsigned</Sign><Endianess>BigEndian</Endianess>
  </IntReg>
  <Enumeration Name="PtpStatus">
""" + "".join(f'    <EnumEntry Name="{k}"><Value>{v}</Value></EnumEntry>\n' for k, v in PTP_STATUS.items()) + """    <pValue>PtpStatusReg</pValue>
  </Enumeration>
"""
IR_FORMAT_VALUES = {"Radiometric": 0, "TemperatureLinear100mK": 1, "TemperatureLinear10mK": 2}
# The camera families the profiles tell apart (rig/drivers/profiles.py), as this fake's XML variants:
#   a700     IRFormat (the XML file as it is)
#   ax5      no IRFormat; TemperatureLinearMode (Off/On) + TemperatureLinearResolution (Low/High:
#            0.4 / 0.04 K per count) and Mono14, as FLIR's A35/A65/Ax5 name them
#   generic  no radiometric feature at all: a plain GigE Vision camera whose Mono16 counts are
#            (kelvin - GENERIC_OFFSET_K) / GENERIC_GAIN_K, which a test states with --kelvin-map
VARIANTS = ("a700", "ax5", "generic")
GENERIC_GAIN_K, GENERIC_OFFSET_K = 0.02, 200.0
IDENTITY = {"a700": ("FLIR Systems AB", "FLIR A700 (thermal4d fake)"),
            "ax5": ("FLIR Systems AB", "FLIR A65 (thermal4d fake)"),
            "generic": ("Generic Vision", "GV-16 (thermal4d fake)")}
IRFORMAT_XML = """  <Enumeration Name="IRFormat">
    <EnumEntry Name="Radiometric"><Value>0</Value></EnumEntry>
    <EnumEntry Name="TemperatureLinear100mK"><Value>1</Value></EnumEntry>
    <EnumEntry Name="TemperatureLinear10mK"><Value>2</Value></EnumEntry>
    <pValue>IRFormatReg</pValue>
  </Enumeration>
"""
TLINEAR_XML = f"""  <Enumeration Name="TemperatureLinearMode">
    <EnumEntry Name="Off"><Value>0</Value></EnumEntry>
    <EnumEntry Name="On"><Value>1</Value></EnumEntry>
    <pValue>IRFormatReg</pValue>
  </Enumeration>
  <IntReg Name="TemperatureLinearResolutionReg">
    <Address>{REG["TemperatureLinearResolution"]:#x}</Address><Length>4</Length><AccessMode>RW</AccessMode>
    <pPort>Device</pPort><Sign>Unsigned</Sign><Endianess>BigEndian</Endianess>
  </IntReg>
  <Enumeration Name="TemperatureLinearResolution">
    <EnumEntry Name="Low"><Value>0</Value></EnumEntry>
    <EnumEntry Name="High"><Value>1</Value></EnumEntry>
    <pValue>TemperatureLinearResolutionReg</pValue>
  </Enumeration>
"""


def variant_xml(variant: str, ptp: bool = False) -> bytes:
    """The GenICam XML of a camera family (see VARIANTS): the A700 file with features renamed or
    removed; ptp: with the SFNC's PtpEnable and PtpStatus."""
    xml = XML_PATH.read_text()
    if ptp:
        xml = xml.replace("</RegisterDescription>", PTP_XML + "</RegisterDescription>")
    assert IRFORMAT_XML in xml and variant in VARIANTS
    if variant == "ax5":
        xml = xml.replace(IRFORMAT_XML, TLINEAR_XML).replace('ModelName="A700"', 'ModelName="A65"')
        xml = xml.replace("<pFeature>IRFormat</pFeature>", "<pFeature>TemperatureLinearMode</pFeature>")
        xml = xml.replace('    <EnumEntry Name="Mono16">',
                          '    <EnumEntry Name="Mono14"><Value>17825829</Value></EnumEntry>\n    <EnumEntry Name="Mono16">')
    elif variant == "generic":
        xml = xml.replace(IRFORMAT_XML, "").replace("<pFeature>IRFormat</pFeature>", "")
        xml = xml.replace('ModelName="A700" VendorName="FLIR"', 'ModelName="GV-16" VendorName="Generic Vision"')
    return xml.encode()
IR_FORMAT_NAMES = {v: k for k, v in IR_FORMAT_VALUES.items()}
READ_ONLY = {REG["SensorWidth"], REG["SensorHeight"], REG["PtpStatus"], *CAL_REG.values()}


def synthetic_scene(width: int = 640, height: int = 480) -> Callable[[float], np.ndarray]:
    """Default frame source: a 293 K gradient with a 310 K blob circling (kelvin, (H, W))."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    base = 290.0 + 6.0 * xx / width + 2.0 * yy / height

    def source(t: float) -> np.ndarray:
        cx = width * (0.5 + 0.3 * math.cos(0.7 * t))
        cy = height * (0.5 + 0.3 * math.sin(0.9 * t))
        blob = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (0.08 * width) ** 2))
        return base + 20.0 * blob
    return source


def world_scene(width: int = 640, height: int = 480, seed: int = 0) -> Callable[[float], np.ndarray]:
    """Frame source from the project's simulated world (rig.sim), seen by rig 0's thermal camera
    (keyframes rendered once at 1/5 size and blended: see rig.simulated.WorldScene)."""
    from rig.sim import make_world
    from rig.simulated import WorldScene
    scene = WorldScene(make_world("default", seed=seed))
    scene.prerender({"thermal": (width, height)})
    return lambda t: scene.temperature(t, width, height)


@dataclass
class FakeConfig:
    width: int = 640
    height: int = 480
    fps: float = 30.0
    pixel_format: str = "Mono16"
    ir_format: str = "TemperatureLinear10mK"
    source: Callable[[float], np.ndarray] | None = None   # time_s -> kelvin (H, W)
    loss: float = 0.0                  # probability each GVSP packet (also resent ones) is lost
    reorder: float = 0.0               # probability a packet is held back 1-4 packets
    duplicate: float = 0.0             # probability a packet is sent twice
    resend: bool = True                # advertise and serve PACKETRESEND
    resend_buffer_frames: int = 16
    nuc_period_s: float = 0.0          # automatic NUC every this many seconds (0: never)
    nuc_duration_s: float = 0.3        # frames pause for this long during a NUC
    nuc_pending_ms: int = 600          # NUCAction acks with PENDING_ACK, then this late
    clock_offset_s: float = 1234.5     # device clock = offset + (1 + drift) * elapsed
    clock_drift_ppm: float = 0.0
    tick_hz: int = 1_000_000_000
    first_block_id: int = 1
    heartbeat_timeout_ms: int = 3000
    zipped_xml: bool = True
    packet_size: int = 1400            # SCPS default until the host writes it
    seed: int = 0
    serial: str = "FAKE0700"
    calibration: flir.RadiometricCalibration = field(default_factory=flir.RadiometricCalibration)
    variant: str = "a700"              # camera family: a700, ax5, generic (VARIANTS)
    path_mtu: int = 1500               # test packets (SCPS fire_test_packet) above this never arrive
    max_packet_size: int = 9000        # sizes the camera can send: above, no test packet (GigE Vision)
    test_packets: bool = True          # answer SCPS fire_test_packet at all
    ptp: str | None = None             # offer IEEE 1588: the port settles as "Slave" (its clock then runs
                                       # drift-free, disciplined) or "Master" (nothing to follow), 0.3 s
                                       # after PtpEnable


class FakeGigECamera:
    def __init__(self, config: FakeConfig | None = None, host: str = "127.0.0.1", port: int = 0):
        self.config = c = config or FakeConfig()
        self.mem = bytearray(MEM_SIZE)
        self.lock = threading.RLock()
        self.rng = random.Random(c.seed)
        self.source = c.source or synthetic_scene(c.width, c.height)
        self.gvcp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gvcp.bind((host, port))
        self.host, self.port = self.gvcp.getsockname()
        self.gvsp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gvsp.bind((host, 0))
        self.gvsp.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
        self.controller: tuple[str, int] | None = None
        self.controller_seen = 0.0
        self.acquiring = False
        self.latched = None                 # (ir_format, params) latched at AcquisitionStart
        self.block_id = c.first_block_id
        self.sent: collections.OrderedDict[int, tuple[bytes, bytes]] = collections.OrderedDict()
        self.nuc_until = 0.0
        self.ptp_enabled_at: float | None = None
        self.stats = collections.Counter()
        self.drop_next_commands = 0         # ignore this many commands (a lost request), then answer
        self.commands: list[tuple[int, int]] = []   # (command, req_id) of every command received
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._held: list[bytes] = []
        self._init_memory()

    @property
    def url(self) -> str:
        return f"gige://{self.host}:{self.port}"

    # -- registers ---------------------------------------------------------------------------
    def _init_memory(self) -> None:
        c = self.config
        m = self.mem
        ip = socket.inet_aton(self.host)
        struct.pack_into(">HH", m, Reg.VERSION, 2, 0)
        m[0x0A:0x10] = bytes([0x00, 0x40, 0x7F, 0x00, 0x07, 0x00])   # FLIR OUI 00:40:7F
        struct.pack_into(">I", m, 0x14, 0x5)                         # current IP config
        m[0x24:0x28] = ip
        vendor, model = IDENTITY[c.variant]
        for off, text in ((0x48, vendor), (0x68, model),
                          (0x88, "1.0"), (0xA8, "tests/fakes/fake_gige.py"), (0xD8, c.serial)):
            m[off:off + len(text)] = text.encode()
        xml = variant_xml(c.variant, ptp=bool(c.ptp))
        if c.zipped_xml:
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
                zf.writestr("FLIR_A700_fake.xml", xml)
            blob, name = buf.getvalue(), "FLIR_A700_fake.zip"
        else:
            blob, name = xml, "FLIR_A700_fake.xml"
        m[XML_ADDRESS:XML_ADDRESS + len(blob)] = blob
        url = f"Local:{name};{XML_ADDRESS:x};{len(blob):x}".encode()
        m[Reg.FIRST_URL:Reg.FIRST_URL + len(url)] = url
        caps = (gvcp.CAP_PACKETRESEND if c.resend else 0) | gvcp.CAP_PENDING_ACK
        self._set(Reg.GVCP_CAPABILITY, caps)
        self._set(Reg.N_STREAM_CHANNELS, 1)
        self._set(Reg.HEARTBEAT_TIMEOUT, c.heartbeat_timeout_ms)
        self._set(Reg.TIMESTAMP_FREQ_HIGH, c.tick_hz >> 32)
        self._set(Reg.TIMESTAMP_FREQ_LOW, c.tick_hz & 0xFFFFFFFF)
        self._set(Reg.SCPS0, c.packet_size)
        self._set(REG["Width"], c.width)
        self._set(REG["Height"], c.height)
        self._set(REG["SensorWidth"], max(c.width, 640))
        self._set(REG["SensorHeight"], max(c.height, 480))
        self._set(REG["PixelFormat"], gvsp.PIXEL_FORMATS[c.pixel_format])
        self._set(REG["IRFormat"], IR_FORMAT_VALUES[c.ir_format] if c.variant == "a700" else 0)
        self._set(REG["FramePeriod"], round(1e6 / c.fps))
        self._set(REG["NUCMode"], 1 if c.nuc_period_s else 0)
        for name, value in vars(flir.ObjectParameters()).items():
            struct.pack_into(">f", m, OBJECT_REG[name], value)
        for name in flir.CALIBRATION_FEATURES:
            value = getattr(c.calibration, name)
            if name == "J0":
                self._set(CAL_REG[name], int(value))
            else:
                struct.pack_into(">f", m, CAL_REG[name], value)

    def _get(self, addr: int) -> int:
        return struct.unpack_from(">I", self.mem, addr)[0]

    def _set(self, addr: int, value: int) -> None:
        struct.pack_into(">I", self.mem, addr, value & 0xFFFFFFFF)

    def _float(self, addr: int) -> float:
        return struct.unpack_from(">f", self.mem, addr)[0]

    def device_ticks(self, t: float | None = None) -> int:
        """The device clock: offset + elapsed x (1 + drift), but drift-free while a PTP slave."""
        c = self.config
        elapsed = (time.monotonic() if t is None else t) - self._t0
        drift = 0.0 if self.ptp_state() == "Slave" else c.clock_drift_ppm * 1e-6
        return int((c.clock_offset_s + elapsed * (1 + drift)) * c.tick_hz)

    def ptp_state(self) -> str:
        if not self.config.ptp or self.ptp_enabled_at is None:
            return "Disabled"
        return self.config.ptp.capitalize() if time.monotonic() - self.ptp_enabled_at > 0.3 else "Listening"

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> FakeGigECamera:
        for target, name in ((self._serve, "fake-gvcp"), (self._stream, "fake-gvsp")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join()
        self.gvcp.close()
        self.gvsp.close()

    def __enter__(self) -> FakeGigECamera:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- GVCP ------------------------------------------------------------------------------
    def _serve(self) -> None:
        self.gvcp.settimeout(0.05)
        while not self._stop.is_set():
            try:
                data, src = self.gvcp.recvfrom(2048)
            except socket.timeout:
                self._check_heartbeat()
                continue
            except OSError:
                return
            with self.lock:
                self._check_heartbeat()
                try:
                    cmd = gvcp.parse_command(data)
                except gvcp.GvcpFormatError:
                    self.stats["malformed_commands"] += 1
                    continue
                self.commands.append((cmd.command, cmd.req_id))
                if self.drop_next_commands > 0:
                    self.drop_next_commands -= 1
                    self.stats["dropped_commands"] += 1
                    continue
                if src == self.controller:
                    self.controller_seen = time.monotonic()
                reply = self._handle(cmd, src)
            if reply is not None and cmd.flags & gvcp.Flag.ACK_REQUIRED:
                self.gvcp.sendto(reply, src)

    def _check_heartbeat(self) -> None:
        with self.lock:
            timeout = self._get(Reg.HEARTBEAT_TIMEOUT) / 1000
            if self.controller and time.monotonic() - self.controller_seen > timeout:
                self.stats["heartbeat_expired"] += 1
                self.controller = None
                self._set(Reg.CCP, 0)
                self.acquiring = False
                self._set(Reg.SCP0, 0)

    def _handle(self, cmd: gvcp.CommandPacket, src) -> bytes | None:
        ack = cmd.command + 1
        self.stats[f"cmd_{cmd.command:04x}"] += 1
        if cmd.command == Command.DISCOVERY:
            return gvcp.build_ack(0, ack, cmd.req_id, bytes(self.mem[:gvcp.BOOTSTRAP_INFO_SIZE]))
        if cmd.command == Command.PACKETRESEND:
            self._resend(cmd)
            return None
        if cmd.command in (Command.READREG, Command.READMEM):
            self._set(REG["PtpStatus"], PTP_STATUS[self.ptp_state()])     # a live status register
        if cmd.command == Command.READREG:
            n = len(cmd.payload) // 4
            addrs = struct.unpack(f">{n}I", cmd.payload[:4 * n])
            if any(a % 4 or a + 4 > MEM_SIZE for a in addrs):
                return gvcp.build_ack(Status.INVALID_ADDRESS, ack, cmd.req_id)
            return gvcp.build_ack(0, ack, cmd.req_id, b"".join(self.mem[a:a + 4] for a in addrs))
        if cmd.command == Command.READMEM:
            if len(cmd.payload) < 8:
                return gvcp.build_ack(Status.INVALID_PARAMETER, ack, cmd.req_id)
            addr, _, count = struct.unpack_from(">IHH", cmd.payload)
            if addr % 4 or count % 4 or count > gvcp.MAX_PAYLOAD or addr + count > MEM_SIZE:
                return gvcp.build_ack(Status.INVALID_PARAMETER, ack, cmd.req_id)
            return gvcp.build_ack(0, ack, cmd.req_id, cmd.payload[:4] + bytes(self.mem[addr:addr + count]))
        if cmd.command in (Command.WRITEREG, Command.WRITEMEM):
            if self.controller is not None and src != self.controller:
                return gvcp.build_ack(Status.ACCESS_DENIED, ack, cmd.req_id)
            if cmd.command == Command.WRITEREG:
                n = len(cmd.payload) // 8
                pairs = [struct.unpack_from(">II", cmd.payload, 8 * i) for i in range(n)]
            else:
                addr = struct.unpack_from(">I", cmd.payload)[0]
                body = cmd.payload[4:]
                pairs = [(addr + i, struct.unpack_from(">I", body, i)[0]) for i in range(0, len(body) - 3, 4)]
            for i, (addr, value) in enumerate(pairs):
                status = self._write(addr, value, src, cmd.req_id)
                if status == "pending":
                    return gvcp.build_ack(0, Command.PENDING_ACK, cmd.req_id,
                                          struct.pack(">HH", 0, self.config.nuc_pending_ms))
                if status:
                    return gvcp.build_ack(status, ack, cmd.req_id, struct.pack(">HH", 0, i))
            return gvcp.build_ack(0, ack, cmd.req_id, struct.pack(">HH", 0, len(pairs)))
        return gvcp.build_ack(Status.NOT_IMPLEMENTED, ack, cmd.req_id)

    def _write(self, addr: int, value: int, src, req_id: int) -> int | str:
        if addr % 4 or addr + 4 > MEM_SIZE:
            return Status.INVALID_ADDRESS
        if addr in READ_ONLY or addr < Reg.CCP and addr not in (Reg.HEARTBEAT_TIMEOUT, Reg.TIMESTAMP_CONTROL):
            return Status.WRITE_PROTECT
        if addr == Reg.CCP:
            self.controller = src if value & (gvcp.CCP_CONTROL | gvcp.CCP_EXCLUSIVE) else None
            self.controller_seen = time.monotonic()
        elif addr == Reg.TIMESTAMP_CONTROL and value & gvcp.TIMESTAMP_LATCH:
            ticks = self.device_ticks()
            self._set(Reg.TIMESTAMP_VALUE_HIGH, ticks >> 32)
            self._set(Reg.TIMESTAMP_VALUE_LOW, ticks)
            return 0
        elif addr == Reg.SCPS0 and value & 0x80000000:       # fire_test_packet (bit 0, MSB-first)
            self._test_packet(value & 0xFFFF)
            value &= 0x7FFFFFFF
        elif addr == REG["PtpEnable"]:
            self.ptp_enabled_at = time.monotonic() if value else None
        elif addr == REG["AcquisitionCommand"]:
            self._acquisition(bool(value))
            return 0
        elif addr == REG["NUCAction"] and value:
            self._start_nuc(src, req_id)
            return "pending"
        self._set(addr, value)
        return 0

    def _test_packet(self, size: int) -> None:
        """One datagram of IP size `size` (IP + UDP headers: 28 bytes) to the stream destination,
        with don't-fragment: lost on a path whose MTU is smaller (self.config.path_mtu)."""
        c = self.config
        self.stats["test_packets"] += 1
        dest = (socket.inet_ntoa(struct.pack(">I", self._get(Reg.SCDA0))), self._get(Reg.SCP0) & 0xFFFF)
        if not c.test_packets or size > c.max_packet_size or size % 4 or dest[1] == 0:
            return
        if size <= c.path_mtu:
            self.gvsp.sendto(bytes(size - 28), dest)

    def _acquisition(self, start: bool) -> None:
        if start and not self.acquiring:
            fmt = self._latched_format()
            params = flir.ObjectParameters(**{n: self._float(a) for n, a in OBJECT_REG.items()})
            self.latched = (fmt, params)
            self.block_id = self.config.first_block_id
        self.acquiring = start

    def _start_nuc(self, src, req_id: int) -> None:
        done_s = self.config.nuc_pending_ms / 1000
        self.nuc_until = time.monotonic() + max(done_s, self.config.nuc_duration_s)
        self.stats["nucs"] += 1

        def finish():
            if not self._stop.is_set():
                self.gvcp.sendto(gvcp.build_ack(0, Command.WRITEREG + 1, req_id, struct.pack(">HH", 0, 1)), src)
        threading.Timer(done_s, finish).start()

    # -- GVSP ------------------------------------------------------------------------------
    def _stream(self) -> None:
        period = 1 / self.config.fps
        next_t = time.monotonic()
        next_auto_nuc = time.monotonic() + self.config.nuc_period_s
        while not self._stop.is_set():
            now = time.monotonic()
            if next_t > now:
                time.sleep(min(next_t - now, 0.05))
                continue
            next_t += period
            if now - next_t > 1.0:              # fell far behind (debugger, overload): skip ahead
                next_t = now + period
            with self.lock:
                period = self._get(REG["FramePeriod"]) / 1e6 or period
                if self.config.nuc_period_s and now >= next_auto_nuc:
                    self.nuc_until = now + self.config.nuc_duration_s
                    next_auto_nuc = now + self.config.nuc_period_s
                    self.stats["nucs"] += 1
                if not self.acquiring or now < self.nuc_until:
                    continue
                dest = (socket.inet_ntoa(struct.pack(">I", self._get(Reg.SCDA0))), self._get(Reg.SCP0) & 0xFFFF)
                if dest[1] == 0:
                    continue
                packet_size = self._get(Reg.SCPS0) & gvcp.SCPS_SIZE_MASK
                w, h = self._get(REG["Width"]), self._get(REG["Height"])
                pixfmt = self._get(REG["PixelFormat"])
                block_id = self.block_id
                self.block_id = gvsp.next_block_id(block_id)
                fmt, params = self.latched
            ticks = self.device_ticks(now)
            data = self._render(now - self._t0, w, h, pixfmt, fmt, params)
            leader = gvsp.build_leader(gvsp.ImageLeader(gvsp.PAYLOAD_TYPE_IMAGE, ticks, pixfmt, w, h))
            self._remember(block_id, leader, data)
            self._send_block(dest, block_id, leader, data, packet_size)
            self.stats["frames"] += 1

    def _latched_format(self) -> str:
        """What the counts mean from this AcquisitionStart on (an IRFormat-style name)."""
        variant, value = self.config.variant, self._get(REG["IRFormat"])
        if variant == "generic":
            return "Counts"
        if variant == "ax5":
            if not value:                  # TemperatureLinearMode Off: raw radiometric counts
                return "Radiometric"
            return ("TemperatureLinear400mK", "TemperatureLinear40mK")[self._get(REG["TemperatureLinearResolution"]) & 1]
        return IR_FORMAT_NAMES.get(value, "TemperatureLinear10mK")

    def _render(self, t: float, w: int, h: int, pixfmt: int, fmt: str, params) -> bytes:
        kelvin = self.source(t)
        if kelvin.shape != (h, w):
            kelvin = cv2.resize(kelvin.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
        if gvsp.bits_per_pixel(pixfmt) == 8:      # AGC video
            lo, hi = float(kelvin.min()), float(kelvin.max())
            return np.clip((kelvin - lo) * 255 / max(hi - lo, 1e-6), 0, 255).astype(np.uint8).tobytes()
        if fmt == "Counts":
            counts = np.clip(np.rint((kelvin - GENERIC_OFFSET_K) / GENERIC_GAIN_K), 0, 65535)
        else:
            counts = flir.kelvin_to_counts(kelvin, fmt, params, self.config.calibration)
        return counts.astype("<u2").tobytes()

    def _remember(self, block_id: int, leader: bytes, data: bytes) -> None:
        with self.lock:
            self.sent[block_id] = (leader, data)
            while len(self.sent) > self.config.resend_buffer_frames:
                self.sent.popitem(last=False)

    def _packets(self, block_id: int, leader: bytes, data: bytes, packet_size: int, first: int,
                 last: int, status: int = 0):
        chunk = gvsp.data_per_packet(packet_size)
        n_data = -(-len(data) // chunk)
        for pid in range(first, min(last, n_data + 1) + 1):
            if pid == 0:
                yield gvsp.build_packet(status, block_id, gvsp.Format.LEADER, 0, leader)
            elif pid == n_data + 1:
                yield gvsp.build_packet(status, block_id, gvsp.Format.TRAILER, pid,
                                        gvsp.build_trailer(gvsp.PAYLOAD_TYPE_IMAGE, struct.unpack_from(">I", leader, 20)[0]))
            else:
                yield gvsp.build_packet(status, block_id, gvsp.Format.PAYLOAD, pid,
                                        data[(pid - 1) * chunk:pid * chunk])

    def _send_block(self, dest, block_id: int, leader: bytes, data: bytes, packet_size: int,
                    first: int = 0, last: int = 1 << 24, status: int = 0) -> None:
        c, rng = self.config, self.rng
        for pkt in self._packets(block_id, leader, data, packet_size, first, last, status):
            if c.loss and rng.random() < c.loss:
                self.stats["lost_packets"] += 1
                continue
            copies = 2 if c.duplicate and rng.random() < c.duplicate else 1
            if c.reorder and rng.random() < c.reorder:
                self._held.append(pkt)
                continue
            for _ in range(copies):
                self._sendto(pkt, dest)
            if self._held and rng.random() < 0.5:
                self._sendto(self._held.pop(0), dest)
        for pkt in self._held:
            self._sendto(pkt, dest)
        self._held.clear()

    def _sendto(self, pkt: bytes, dest) -> None:
        try:
            self.gvsp.sendto(pkt, dest)
            self.stats["packets"] += 1
        except OSError:
            self.stats["send_errors"] += 1

    def _resend(self, cmd: gvcp.CommandPacket) -> None:
        self.stats["resend_requests"] += 1
        if not self.config.resend:
            return
        extended = bool(cmd.flags & gvcp.Flag.EXTENDED_IDS)
        try:
            _, block_id, first, last = gvcp.parse_packetresend(cmd.payload, extended)
        except gvcp.GvcpFormatError:
            return
        dest = (socket.inet_ntoa(struct.pack(">I", self._get(Reg.SCDA0))), self._get(Reg.SCP0) & 0xFFFF)
        packet_size = self._get(Reg.SCPS0) & gvcp.SCPS_SIZE_MASK
        sent = self.sent.get(block_id)
        if sent is None:
            self._sendto(gvsp.build_packet(Status.PACKET_UNAVAILABLE, block_id, gvsp.Format.PAYLOAD, first, b""), dest)
            return
        self.stats["resent_packets"] += last - first + 1
        self._send_block(dest, block_id, *sent, packet_size, first, last, status=Status.PACKET_RESEND)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Fake FLIR A700 GigE Vision camera on loopback.")
    p.add_argument("--port", type=int, default=0, help="GVCP port (0: any free one)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--loss", type=float, default=0.0, help="GVSP packet loss probability")
    p.add_argument("--reorder", type=float, default=0.0)
    p.add_argument("--duplicate", type=float, default=0.0)
    p.add_argument("--scene", choices=["synthetic", "world"], default="synthetic",
                   help="frames of a synthetic warm blob, or of the simulated world (rig.sim)")
    p.add_argument("--prerender", type=int, default=30, help="frames rendered once and cycled")
    args = p.parse_args(argv)
    scene = (world_scene if args.scene == "world" else synthetic_scene)(args.width, args.height)
    frames = [scene(i / args.fps) for i in range(args.prerender)]
    cfg = FakeConfig(width=args.width, height=args.height, fps=args.fps, loss=args.loss,
                     reorder=args.reorder, duplicate=args.duplicate,
                     source=lambda t: frames[int(t * args.fps) % len(frames)])
    cam = FakeGigECamera(cfg, port=args.port).start()
    print(cam.url, flush=True)
    try:
        sys.stdin.read()          # run until stdin closes
    finally:
        print(json.dumps(dict(cam.stats)), file=sys.stderr, flush=True)
        cam.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
