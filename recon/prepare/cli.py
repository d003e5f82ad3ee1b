"""`recon prepare SESSION OUT`: a rig session -> a prepared dataset with recovered poses; or
`recon prepare RGBT_DIR OUT`: an RGBT-Scenes folder (rgb/, thermal/, sparse/0/ COLMAP model) -> a
prepared dataset with the model's poses (docs/import.md)."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from recon.prepare.frames import PrepareError
from recon.prepare.pipeline import REPORT_FILE, PrepareOptions, prepare_session
from recon.prepare.report import Report
from rig.cli_format import positive_float, positive_int

EPILOG = """\
examples:
  rig capture --duration 10 --sim-keyframes 30 --sim-render-scale 0.5 --out sessions/s1
  recon prepare sessions/s1 data/s1                       # calibration found beside the session
  recon prepare sessions/s1 data/s1 --calibration rigs/rig_calibration.json --frames 120
  recon prepare sessions/s1 data/s1 --scale 0.35 --downscale 2   # metres per SfM unit given
  recon run data/s1 --out runs/s1
  recon prepare scenes/building data/building --thermal-aligned --non-radiometric   # RGBT-Scenes layout
  recon prepare scenes/lab data/lab --thermal-scale 0.01 --times lab_times.csv      # 16-bit, timed

Calibration: --calibration, else SESSION/rig_calibration.json, else the session folder's parent
rig_calibration.json (`rig calibrate` writes it), else, for simulated sessions only, the
simulator's true calibration. Metric scale: --scale, else the calibration checkerboard seen in
>= 3 registered phone frames, else, for simulated sessions only, the simulator's true camera
path; when none applies the command refuses. Simulator fallbacks are noted in the report.
Writes OUT/transforms.json, rgb/, thermal/, points3d.ply and prepare_report.json (also on
failure: status, error and what was measured). Exit status 1 = refused, with advice; 2 = bad
arguments or malformed input (one line naming the file).

RGBT-Scenes folder (rgb/ + thermal/ + sparse/0 or sparse/ with cameras, images, points3D .bin or
.txt): no SfM, the model's poses and intrinsics are used. Thermal poses: the model's where it
registers thermal images, else --thermal-aligned (thermal registered to the RGB view) or
--calibration + --scale (metres per model unit); else it refuses. Splits from rgb/train and
rgb/test when present, else --test-every. Times: --times CSV, else static (all 0). 8-bit or
colour-mapped thermal is refused unless --non-radiometric. --downscale applies; --frames,
--matching, --mask and the SfM checks apply to sessions only.
"""


def _box(text: str) -> tuple[float, float, float, float]:
    try:
        box = tuple(float(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4 or not (0 <= box[0] < box[2] <= 1 and 0 <= box[1] < box[3] <= 1):
        raise argparse.ArgumentTypeError(f"mask box must be x0,y0,x1,y1 fractions in [0, 1], got {text!r}")
    return box


def register(sub) -> None:
    d = PrepareOptions()
    p = sub.add_parser("prepare", help="rig session -> prepared dataset (sync, SfM poses, thermal poses)",
                       description=__doc__, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", type=Path, metavar="SESSION",
                   help="session folder written by `rig capture` / `rig import`, or an RGBT-Scenes folder")
    p.add_argument("out", type=Path, metavar="OUT", help="new (or empty) dataset folder")
    p.add_argument("--calibration", type=Path, help="rig_calibration.json (default: found beside the session)")
    p.add_argument("--frames", type=positive_int, default=d.frames,
                   help=f"time steps picked over the session, one RGB + one thermal frame each (default: {d.frames})")
    p.add_argument("--test-every", type=int, default=d.test_every,
                   help=f"hold out every n-th time step as test, 0 = none (default: {d.test_every})")
    p.add_argument("--scale", type=float, help="metres per SfM unit (default: the calibration checkerboard "
                                               "in view, else the simulator's truth for simulated sessions)")
    p.add_argument("--downscale", type=positive_int, default=d.downscale,
                   help=f"integer factor for the written images (default: {d.downscale})")
    p.add_argument("--matching", choices=("sequential", "exhaustive"), default=d.matching,
                   help=f"pycolmap pairing; sequential adds loop-closure keyframe pairs (default: {d.matching})")
    p.add_argument("--mask", type=_box, metavar="X0,Y0,X1,Y1",
                   help="image region ignored by SfM and left unmeasured in thermal, as fractions "
                        "(default: the sync lamp's box recorded in a simulated session)")
    p.add_argument("--min-registered", type=float, default=d.min_registered,
                   help=f"refuse below this fraction of registered frames (default: {d.min_registered})")
    p.add_argument("--max-reprojection", type=float, default=d.max_reprojection_px,
                   help=f"refuse above this mean reprojection error, px (default: {d.max_reprojection_px})")
    p.add_argument("--max-jitter", type=float, default=d.max_jitter_deg,
                   help=f"refuse above this median path jitter, deg (default: {d.max_jitter_deg})")
    p.add_argument("--refine-intrinsics", action="store_true",
                   help="let bundle adjustment refine the calibrated phone intrinsics (default: fixed)")
    p.add_argument("--threads", type=positive_int, default=d.threads, help=f"pycolmap threads (default: {d.threads})")
    p.add_argument("--keep-work", action="store_true", help="keep OUT/.work (SfM images, database, model)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    g = p.add_argument_group("RGBT-Scenes folders")
    g.add_argument("--thermal-aligned", action="store_true",
                   help="thermal frames are registered to the RGB view of the same name (same pose)")
    g.add_argument("--thermal-scale", type=positive_float, metavar="K",
                   help="kelvin per count of 16-bit thermal frames (default: 0.01 or 0.1 by the median)")
    g.add_argument("--times", type=Path, metavar="CSV",
                   help="file,timestamp rows giving each image's time (default: static, time 0)")
    g.add_argument("--non-radiometric", action="store_true",
                   help="accept 8-bit (colour-mapped) thermal as grey levels, not temperatures")
    p.set_defaults(func=run)


def run(args) -> int:
    options = dict(calibration=args.calibration, frames=args.frames, test_every=args.test_every, scale=args.scale,
                   downscale=args.downscale, matching=args.matching, mask_box=args.mask,
                   min_registered=args.min_registered, max_reprojection_px=args.max_reprojection,
                   max_jitter_deg=args.max_jitter, refine_intrinsics=args.refine_intrinsics,
                   threads=args.threads, keep_work=args.keep_work, thermal_aligned=args.thermal_aligned,
                   thermal_scale=args.thermal_scale, times=args.times, non_radiometric=args.non_radiometric)
    try:
        PrepareOptions(**options)
    except ValueError as exc:
        print(f"recon prepare: {exc}", file=sys.stderr)
        return 2
    if args.out.exists() and any(args.out.iterdir()):
        print(f"recon prepare: {args.out} exists and is not empty; choose a new output folder", file=sys.stderr)
        return 2
    code, error, start = 0, None, time.time()
    try:
        prepare_session(args.session, args.out, progress=lambda m: print(f"  {m}", flush=True), **options)
    except PrepareError as exc:
        code, error = 1, str(exc)
    report_path = args.out / REPORT_FILE
    if report_path.is_file() and report_path.stat().st_mtime >= start - 1:     # written by this run
        data = json.loads(report_path.read_text())
        if args.json:
            print(json.dumps(data, indent=1))
        else:
            print("\n".join(line for line in Report(**data).summary_lines() if not line.startswith("error")))
    if error:
        print(f"recon prepare: refused: {error}", file=sys.stderr)
    return code
