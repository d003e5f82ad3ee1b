"""A GigE Vision camera = control channel + GenApi features + one stream channel.

    cam = GigECamera.open("gige://192.168.1.20")
    cam.features.set("PixelFormat", "Mono16")
    stream = cam.start_stream()
    frame = stream.get(timeout=1.0)
    cam.close()
"""
from __future__ import annotations

import logging
from dataclasses import replace
from urllib.parse import urlparse

from rig.drivers.gige import gvcp, gvsp
from rig.drivers.gige.device import ControlConfig, GigEDevice, discover
from rig.drivers.gige.features import Features
from rig.drivers.gige.packet_size import MAX_SIZE, PacketSizeResult, negotiate_packet_size
from rig.drivers.gige.stream import GvspStream, StreamConfig

log = logging.getLogger(__name__)


def parse_camera_url(url: str) -> tuple[str, int]:
    """`gige://HOST[:PORT]` (or a bare HOST[:PORT]) -> (host, GVCP port)."""
    parsed = urlparse(url if "://" in url else f"gige://{url}")
    if parsed.scheme != "gige" or not parsed.hostname:
        raise ValueError(f"camera {url!r}: expected gige://HOST[:PORT]")
    return parsed.hostname, parsed.port or gvcp.GVCP_PORT


class GigECamera:
    def __init__(self, device: GigEDevice, info: gvcp.DeviceInfo | None, features: Features):
        self.device = device
        self.info = info
        self.features = features
        self.stream: GvspStream | None = None
        self.packet_size: PacketSizeResult | None = None      # once negotiated (packet_size 0)
        self.tick_hz = device.timestamp_frequency() or 1_000_000_000

    @classmethod
    def open(cls, url: str, control: ControlConfig | None = None, exclusive: bool = False,
             discovery_timeout_s: float = 0.5) -> GigECamera:
        """Connect, identify (unicast DISCOVERY), take control, load the GenICam features."""
        host, port = parse_camera_url(url)
        found = discover([host], port=port, timeout_s=discovery_timeout_s)
        device = GigEDevice(host, port, control)
        try:
            device.take_control(exclusive=exclusive)
            return cls(device, found[0] if found else None, Features(device))
        except BaseException:
            device.close()
            raise

    @property
    def resend_supported(self) -> bool:
        return bool(self.device.capabilities() & gvcp.CAP_PACKETRESEND)

    def geometry(self) -> gvsp.ImageLeader:
        f = self.features
        pixfmt = gvsp.PIXEL_FORMATS.get(f.get("PixelFormat"))
        if pixfmt is None:
            raise ValueError(f"unsupported pixel format {f.get('PixelFormat')!r}")
        return gvsp.ImageLeader(gvsp.PAYLOAD_TYPE_IMAGE, 0, pixfmt, int(f.get("Width")),
                                int(f.get("Height")))

    def negotiate_packet_size(self) -> PacketSizeResult:
        """The stream packet size the path carries (test packets; once per camera), within the
        camera's GevSCPSPacketSize maximum where its XML states one."""
        if self.packet_size is None:
            hi = MAX_SIZE
            if self.features.has("GevSCPSPacketSize"):
                try:
                    hi = min(hi, int(self.features.node("GevSCPSPacketSize").max))
                except Exception:    # noqa: BLE001 - no readable maximum: keep 9000
                    pass
            self.packet_size = negotiate_packet_size(self.device, hi=hi)
            log.info("%s: %s", self.device.address, self.packet_size.describe())
        return self.packet_size

    def start_stream(self, config: StreamConfig | None = None) -> GvspStream:
        """Open the receiver, point stream channel 0 at it, AcquisitionStart."""
        config = config or StreamConfig()
        if self.stream is None and config.packet_size == 0:
            config = replace(config, packet_size=self.negotiate_packet_size().size)
        if self.stream is None:
            self.stream = GvspStream(self.geometry(), self.device.address, self.device.port,
                                     host_ip=self.device.host_address(), config=config,
                                     resend_supported=config.resend and self.resend_supported)
            self.stream.start()
            self.device.configure_stream_channel(self.device.host_address(), self.stream.port,
                                                 config.packet_size)
        self.stream.reset_sequence()
        self.features.execute("AcquisitionStart")
        return self.stream

    def stop_acquisition(self) -> None:
        """AcquisitionStop, then deliver the frames still in flight (ids restart on the next start)."""
        self.features.execute("AcquisitionStop")
        if self.stream is not None:
            self.stream.drain()

    def close(self) -> None:
        try:
            if self.stream is not None:
                try:
                    self.stop_acquisition()
                    self.device.stop_stream_channel()
                except Exception as exc:       # the device may be gone; still release locally
                    log.warning("stopping %s: %s", self.device.address, exc)
                self.stream.close()
                self.stream = None
        finally:
            self.device.close()

    def __enter__(self) -> GigECamera:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
