"""`rig devices`: what is plugged in: GigE Vision cameras, serial sync boxes, phones."""
from __future__ import annotations

import json
import os
from dataclasses import asdict

from rig.cli_format import HelpFormatter

APPLE_VID = 0x05AC


def gige_cameras(timeout_s: float = 0.5, probe: bool = True) -> list[dict]:
    """Discovered GigE Vision cameras; with probe, each one's profile (rig/drivers/profiles.py),
    read from its GenICam XML (control is taken for a moment and released)."""
    from rig.drivers.gige import discover
    from rig.drivers.profiles import describe
    return [{**asdict(d), "url": d.url, **(describe(d.url) if probe else {})} for d in discover(timeout_s=timeout_s)]


def serial_boxes() -> list[dict]:
    from rig.drivers.syncbox import list_serial_ports
    return list_serial_ports()


def phones() -> tuple[list[dict], str | None]:
    """Apple USB devices. -> (devices, why none could be listed, or None)."""
    try:
        import usb.core
    except ImportError:
        return [], "pyusb is not installed"
    try:
        devs = list(usb.core.find(idVendor=APPLE_VID, find_all=True))
    except usb.core.NoBackendError:
        return [], "libusb is not installed (apt-get install libusb-1.0-0)"
    except usb.core.USBError as exc:
        return [], f"USB: {exc}"
    out = []
    for d in devs:
        entry = {"vid": d.idVendor, "pid": d.idProduct, "bus": d.bus, "address": d.address}
        try:
            entry["product"] = usb.util.get_string(d, d.iProduct)
            entry["serial"] = usb.util.get_string(d, d.iSerialNumber)
        except (usb.core.USBError, ValueError, NotImplementedError):
            entry["product"] = None          # strings need permission; presence is enough
        entry["is_phone"] = entry.get("product") is None or "iphone" in (entry["product"] or "").lower()
        out.append(entry)
    note = None if out or os.path.isdir("/dev/bus/usb") else "no /dev/bus/usb on this machine"
    return out, note


def register(sub) -> None:
    p = sub.add_parser("devices", help="list GigE cameras, serial sync boxes and phones",
                       description="Discover GigE Vision cameras (broadcast on every interface and "
                                   "127.0.0.1), list serial ports (sync boxes by USB vendor id) and "
                                   "Apple USB devices (phones).",
                       formatter_class=HelpFormatter,
                       epilog="example:\n  rig devices --json")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--timeout", type=float, default=0.5, help="GigE discovery wait, seconds")
    p.add_argument("--no-probe", action="store_true",
                   help="do not open each camera to read which profile it gets (a camera another host "
                        "controls cannot be probed)")
    p.set_defaults(func=main)


def main(args) -> int:
    cams = gige_cameras(args.timeout, probe=not args.no_probe)
    ports = serial_boxes()
    phone_list, phone_note = phones()
    if args.json:
        print(json.dumps({"gige": cams, "serial": ports, "phones": phone_list, "phones_note": phone_note}, indent=1))
        return 0
    print("GigE Vision cameras:")
    for c in cams:
        print(f"  {c['url']:28s} {c['manufacturer']} {c['model']} serial {c['serial']} (mac {c['mac']})")
        if c.get("profile"):
            kind = "radiometric" if c["radiometric"] else "counts only: --kelvin-map for temperatures"
            print(f"  {'':28s} profile {c['profile']} ({kind}), pixel formats {', '.join(c['pixel_formats'])}")
        elif c.get("error"):
            print(f"  {'':28s} profile unknown: {c['error']}")
    if not cams:
        print("  none answered discovery")
    print("Serial ports:")
    for p in ports:
        ids = f"{p['vid']:04x}:{p['pid']:04x}" if p["vid"] is not None else "no USB id"
        tag = f"  <- {p['chip']}, likely a sync box" if p["likely_syncbox"] else ""
        print(f"  {p['port']:28s} {ids} {p['description']}{tag}")
    if not ports:
        print("  none")
    print("Phones (Apple USB):")
    for d in phone_list:
        print(f"  bus {d['bus']} address {d['address']}  {d['vid']:04x}:{d['pid']:04x} {d.get('product') or ''}")
    if not phone_list:
        print(f"  none{f' ({phone_note})' if phone_note else ''}")
    return 0
