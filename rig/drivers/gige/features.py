"""GenICam features: fetch the device's XML and evaluate it with the PyPI `genicam` GenApi.

The first-URL register (0x0200, 512 bytes; 0x0400 as a fallback) names where
the XML lives; `Local:` URLs point into device memory, read with READMEM, and
a `.zip` name means a zip archive whose first member is the XML. GenApi reads
and writes registers through `DevicePort`, so every feature access is GVCP.
"""
from __future__ import annotations

import io
import zipfile
from pathlib import Path

from genicam import genapi

from rig.drivers.gige import gvcp
from rig.drivers.gige.device import GigEDevice


class GenicamXmlError(RuntimeError):
    """The device's GenICam XML could not be located or read."""


def read_genicam_url(device: GigEDevice) -> gvcp.GenicamUrl:
    errors = []
    for reg in (gvcp.Reg.FIRST_URL, gvcp.Reg.SECOND_URL):
        text = device.read_string(reg, gvcp.URL_SIZE)
        try:
            return gvcp.parse_genicam_url(text)
        except gvcp.GvcpFormatError as exc:
            errors.append(str(exc))
    raise GenicamXmlError(f"{device.address}: no usable GenICam URL ({'; '.join(errors)})")


def fetch_genicam_xml(device: GigEDevice) -> str:
    """The device's GenApi XML text (unzipped if needed)."""
    url = read_genicam_url(device)
    if url.scheme == "local":
        raw = device.read_mem(url.address, url.length)
    elif url.scheme == "file":
        raw = Path(url.name).read_bytes()
    else:
        raise GenicamXmlError(f"{device.address}: GenICam XML at {url.name} needs a download, "
                              "which thermal4d never does at run time; save it and pass it as a file")
    if url.zipped:
        try:
            with zipfile.ZipFile(io.BytesIO(raw)) as zf:
                raw = zf.read(zf.namelist()[0])
        except (zipfile.BadZipFile, IndexError) as exc:
            raise GenicamXmlError(f"{device.address}: {url.name} is not a readable zip: {exc}") from exc
    return raw.rstrip(b"\0").decode("utf-8")


class DevicePort(genapi.AbstractPort):
    """GenApi port whose reads and writes go over GVCP (READREG/WRITEREG for one aligned
    register, READMEM/WRITEMEM otherwise, as Aravis does)."""

    def __init__(self, device: GigEDevice):
        super().__init__()
        self.device = device

    def is_open(self) -> bool:
        return True

    def get_access_mode(self):
        return genapi.EAccessMode.RW

    def read(self, address: int, length: int) -> bytes:
        if length == 4 and address % 4 == 0:
            return self.device.read_reg(address).to_bytes(4, "big")
        return self.device.read_mem(address, length)

    def write(self, address: int, value) -> None:
        value = bytes(value)
        if len(value) == 4 and address % 4 == 0:
            self.device.write_reg(address, int.from_bytes(value, "big"))
        else:
            self.device.write_mem(address, value)


class Features:
    """GenApi features of one device: `get("Width")`, `set("PixelFormat", "Mono16")`,
    `execute("AcquisitionStart")`; enumerations read and write their entry names."""

    def __init__(self, device: GigEDevice, xml: str | None = None):
        self.xml = xml if xml is not None else fetch_genicam_xml(device)
        self.node_map = genapi.NodeMap()
        self.node_map.load_xml_from_string(self.xml)
        self._port = DevicePort(device)       # the node map does not keep its port alive
        self.node_map.connect(self._port, "Device")

    def has(self, name: str) -> bool:
        return self.node_map.has_node(name) and genapi.is_implemented(self.node_map.get_node(name))

    def node(self, name: str):
        if not self.node_map.has_node(name):
            raise KeyError(f"the device's GenICam XML has no feature {name!r}")
        return self.node_map.get_node(name)

    def get(self, name: str):
        return self.node(name).value

    def set(self, name: str, value) -> None:
        self.node(name).value = value

    def execute(self, name: str) -> None:
        self.node(name).execute()
