"""`rig capture` on the command line: options, the status page beside it (--serve), one-line errors."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.capture.config import CaptureConfig
from rig.capture.session_capture import Capture
from rig.cli_format import HelpFormatter, positive_float
from rig.drivers import flir
from rig.drivers.generic_gige import KelvinMap
from rig.drivers.gige import GvcpError
from rig.drivers.profiles import PROFILES
from rig.drivers.gige.features import GenicamXmlError
from rig.drivers.syncbox import SyncBoxError
from rig.sim.tabletop import VARIANTS
from server.cli_options import add_serve_arguments, serve_from_args


def packet_size(text: str) -> int:
    """argparse type: 'auto' (0) or a packet size in 576..9000, a multiple of 4."""
    if text == "auto":
        return 0
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto or a number of bytes, got {text!r}") from None
    if not 576 <= value <= 9000 or value % 4:
        raise argparse.ArgumentTypeError(f"{value}: a packet size is 576..9000 bytes and a multiple of 4")
    return value


def register(sub) -> None:
    p = sub.add_parser(
        "capture", help="record a session (simulated rig when no device is named)",
        description="Record thermal frames, phone videos and sync-box markers into a crash-safe\n"
                    "session folder (see docs/rig.md, 'Session folder').\n"
                    "With no --camera, --phone-drop or --syncbox the simulated rig is captured (thermal\n"
                    "camera, phone and sync-box lamp). With --phone-drop and/or --syncbox but no --camera,\n"
                    "those devices are recorded beside the simulated thermal camera (no simulated phone\n"
                    "or lamp then: they would show another scene than the real devices).",
        formatter_class=HelpFormatter,
        epilog="examples:\n  rig capture --duration 10 --out /tmp/s1            # simulated rig\n"
               "  rig capture --phone-drop ~/Drop --duration 30      # real phone, simulated thermal camera\n"
               "  rig capture --camera gige://192.168.1.20 --phone-drop ~/Drop --syncbox /dev/ttyACM0\n"
               "  rig capture --camera gige://192.168.1.30 --kelvin-map 0.01,0   # a non-FLIR camera\n"
               "  rig info /tmp/s1 --json")
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds to record")
    p.add_argument("--camera", help="thermal camera, gige://HOST[:PORT] (not named: simulated)")
    p.add_argument("--phone-drop", type=Path, help="folder where the phone's files arrive")
    p.add_argument("--syncbox", help="serial port of the sync box, e.g. /dev/ttyACM0")
    p.add_argument("--out", type=Path, help="session folder to create (default sessions/<date-time>)")
    p.add_argument("--ir-format", default="TemperatureLinear10mK", choices=flir.IR_FORMATS,
                   help="FLIR IRFormat family: what the counts mean (10 mK: up to 382 C; 100 mK: hotter)")
    p.add_argument("--profile", default="auto", choices=["auto", *PROFILES],
                   help="camera profile; auto: from the camera's GenICam features (`rig devices` shows it)")
    p.add_argument("--kelvin-map", metavar="GAIN,OFFSET|FILE.json",
                   help="generic profile: kelvin = counts x GAIN + OFFSET (a non-radiometric camera's own "
                        "calibration); without it a generic camera records counts only")
    p.add_argument("--no-ptp", action="store_true",
                   help="leave IEEE 1588 off (by default it is enabled where the camera offers it; a PTP "
                        "slave's timestamps run at the grandmaster's rate and sync only fits their offset)")
    p.add_argument("--fps", type=positive_float, help="thermal frame rate (default: FLIR 30 Hz, others as set)")
    p.add_argument("--packet-size", type=packet_size, default=0, metavar="auto|BYTES",
                   help="GVSP packet size (SCPS) incl. IP/UDP/GVSP headers; auto: the largest test packet "
                        "that crosses the path (jumbo frames if every hop carries them), 1500 if the camera "
                        "fires none")
    p.add_argument("--settle", type=float, default=1.0, help="seconds a dropped file must stay unchanged")
    p.add_argument("--seed", type=int, default=0, help="simulated rig: scene seed")
    p.add_argument("--sim-scene", choices=["world", "calibration", "synthetic"], default="world",
                   help="simulated rig: the project's simulated world, its heated checkerboard (for "
                        "rig calibrate), or cheap synthetic warm blobs")
    p.add_argument("--sim-variant", default="default", choices=VARIANTS, help="simulated world: variant")
    p.add_argument("--sim-keyframes", type=float, default=5.0, metavar="HZ",
                   help="simulated world: keyframes per second (blended between; 30 for sharp moving views)")
    p.add_argument("--sim-render-scale", type=float, default=0.2, metavar="S",
                   help="simulated world: keyframes rendered at S x 640x480 and upscaled")
    p.add_argument("--sim-segment", type=positive_float, default=10.0, metavar="S",
                   help="simulated phone: seconds per movie file (a file reaches the session only once "
                        "it is written: shorter files give `recon run --follow` its first poses sooner)")
    p.add_argument("--no-sim-lamp", action="store_true",
                   help="simulated rig without its sync-box lamp: sync falls back to cross-correlation")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_serve_arguments(p)
    p.set_defaults(func=main)


def main(args) -> int:
    if args.duration <= 0:
        print("rig capture: --duration must be positive", file=sys.stderr)
        return 2
    cfg = CaptureConfig(duration_s=args.duration, out=args.out, camera=args.camera,
                        phone_drop=args.phone_drop, syncbox=args.syncbox, ir_format=args.ir_format,
                        packet_size=args.packet_size, settle_s=args.settle, seed=args.seed,
                        sim_lamp=not args.no_sim_lamp, sim_scene=args.sim_scene, sim_variant=args.sim_variant,
                        sim_keyframe_hz=args.sim_keyframes, sim_render_scale=args.sim_render_scale,
                        sim_segment_s=args.sim_segment,
                        progress=not args.quiet, profile=args.profile, frame_rate=args.fps,
                        ptp=not args.no_ptp)
    handle = None
    try:
        cfg.kelvin_map = KelvinMap.parse(args.kelvin_map) if args.kelvin_map else None
        cap = Capture(cfg)
        handle = serve_from_args(args, session_dir=cap.out)
        summary = cap.run()
    except (FileExistsError, NotADirectoryError, ValueError, OSError, SyncBoxError, GvcpError,
            GenicamXmlError) as exc:
        print(f"rig capture: {exc}", file=sys.stderr)
        return 2
    finally:
        if handle:
            handle.stop()
    print(cap.out)
    return 1 if summary["stats"]["errors"] else 0
