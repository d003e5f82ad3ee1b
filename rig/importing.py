"""`rig import thermal FRAMES_DIR --out SESSION`: a folder of radiometric thermal frames recorded
by another tool (16-bit PNG or TIFF counts, with timestamps), plus phone videos or photos, into a
session folder exactly as `rig capture` writes one (docs/rig.md), so `rig info`, `recon prepare`
and `recon run` take it. See docs/import.md.

Clock. A session keeps every time on one host clock and places each phone file at its
`creationdate` + PTS, then finds the file's offset (phone clock error, creationdate's whole
seconds) by cross-correlating its motion energy with the thermal temperature-change energy,
searching -0.6..+1.5 s around that nominal start (`rig.sync`). The import makes the host clock
**Unix time** (session.json host_clock {monotonic_ns: 0, realtime_ns: 0}), the clock the
phone's creationdate is on, and puts the thermal frames on it:
- absolute timestamps (Unix seconds, date-times in file names or the CSV) are used as they are;
- relative ones (seconds from any origin, `--fps`) start at `--start` (the wall-clock time of the
  first thermal frame), else at the first phone video's creation date (both recordings assumed
  started together, a warning says so), else at the first frame file's modification time.
Thermal `device_ts` is then the same clock in ns (tick 1 GHz), so the thermal clock fit is exact.
"""
from __future__ import annotations

import csv
import datetime as dt
import platform
import re
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from rig.cli_format import HelpFormatter, positive_float
from rig.sync import change_energy, thumbnail

FRAME_SUFFIXES = {".png", ".tif", ".tiff"}
FORMATS = {"TemperatureLinear10mK": 0.01, "TemperatureLinear100mK": 0.1}
ABSOLUTE_AFTER_S = 1e8              # timestamps above this (1973) are Unix time, below: relative
PLAUSIBLE_K = (150.0, 500.0)        # median scene temperature that identifies the scale
BATCH = 64

# file-name timestamp patterns, tried in this order (the first that matches every file is used)
_DATETIME = re.compile(r"(?<!\d)(\d{4})(\d{2})(\d{2})[T_-]?(\d{2})(\d{2})(\d{2})(?:[._-](\d{1,9}))?(?!\d)")
_UNIT = re.compile(r"(?<![\d.])(\d+(?:\.\d+)?)(ns|us|ms|s)$", re.IGNORECASE)
_EPOCH = re.compile(r"(?<![\d.])(\d{10}|\d{13}|\d{16}|\d{19})(?:\.(\d+))?(?![\d])")
UNIT_S = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}
PATTERNS_HELP = ("a date-time YYYYMMDD[T_-]HHMMSS[.fff] (UTC), a number with a unit at the end of the "
                 "name (123456us, 12.5ms, 3.25s), or a Unix time of 10/13/16/19 digits (s/ms/us/ns)")


class FrameImportError(ValueError):
    """Bad input for an import: the message names the file."""


def natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def parse_time(text: str, where: str) -> float:
    """Seconds (a number) or an ISO 8601 date-time (naive = UTC) -> float seconds."""
    s = text.strip()
    try:
        return float(s)
    except ValueError:
        pass
    try:
        t = dt.datetime.fromisoformat(s.replace("Z", "+00:00"))
    except ValueError:
        raise FrameImportError(f"{where}: {text!r} is neither seconds nor an ISO 8601 date-time") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    return t.timestamp()


def name_timestamp(stem: str) -> tuple[float, str] | None:
    """The timestamp in a file name (without suffix) and which pattern gave it, or None."""
    m = _DATETIME.search(stem)
    if m:
        y, mo, d, h, mi, s, frac = m.groups()
        try:
            t = dt.datetime(int(y), int(mo), int(d), int(h), int(mi), int(s), tzinfo=dt.timezone.utc)
        except ValueError:
            t = None
        if t is not None:
            return t.timestamp() + (float(f"0.{frac}") if frac else 0.0), "date-time"
    m = _UNIT.search(stem)
    if m:
        return float(m.group(1)) * UNIT_S[m.group(2).lower()], f"number with unit {m.group(2).lower()}"
    m = _EPOCH.search(stem)
    if m:
        digits, frac = m.groups()
        unit = {10: 1.0, 13: 1e-3, 16: 1e-6, 19: 1e-9}[len(digits)]
        return int(digits) * unit + (float(f"0.{frac}") * unit if frac else 0.0), f"Unix time ({len(digits)} digits)"
    return None


def read_timestamp_csv(path: Path) -> dict[str, float]:
    """`file,timestamp` rows (a header row is allowed) -> {file name: seconds}."""
    out: dict[str, float] = {}
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise FrameImportError(f"{path}: not a text CSV file") from None
    for n, row in enumerate(csv.reader(text.splitlines()), 1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if len(row) < 2:
            raise FrameImportError(f"{path}: line {n}: expected file,timestamp, got {','.join(row)!r}")
        name, value = row[0].strip(), row[1].strip()
        if n == 1 and not re.match(r"^[\d.+-]", value):
            continue                                     # header
        out[Path(name).name] = parse_time(value, f"{path}: line {n}")
    if not out:
        raise FrameImportError(f"{path}: no file,timestamp rows")
    return out


def list_frames(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise FrameImportError(f"{folder}: not a folder of thermal frames")
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES
                    and not p.name.startswith(".")), key=lambda p: natural_key(p.name))
    if len(files) < 3:
        raise FrameImportError(f"{folder}: {len(files)} PNG/TIFF frames found, at least 3 are needed")
    return files


def frame_times(files: list[Path], csv_path: Path | None, fps: float | None) -> tuple[np.ndarray, str]:
    """Seconds per frame (same order as files) and how they were found."""
    if csv_path is not None:
        table = read_timestamp_csv(csv_path)
        missing = [f.name for f in files if f.name not in table]
        if missing:
            raise FrameImportError(f"{csv_path}: no timestamp for {missing[0]}"
                               + (f" (and {len(missing) - 1} more frames)" if len(missing) > 1 else ""))
        return np.array([table[f.name] for f in files]), f"csv {csv_path}"
    if fps is not None:
        return np.arange(len(files)) / fps, f"--fps {fps:g} (frames in natural name order)"
    times, kinds = [], set()
    for f in files:
        found = name_timestamp(f.stem)
        if found is None:
            raise FrameImportError(f"{f}: no timestamp in the file name (accepted: {PATTERNS_HELP}); "
                               f"give --timestamps CSV or --fps")
        times.append(found[0])
        kinds.add(found[1])
    if len(kinds) > 1:
        raise FrameImportError(f"{files[0].parent}: file names mix timestamp patterns ({', '.join(sorted(kinds))}); "
                           f"give --timestamps CSV")
    return np.array(times), f"file names ({kinds.pop()})"


def read_counts(path: Path) -> np.ndarray:
    """A 16-bit single-channel radiometric frame, or an FrameImportError naming the file."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FrameImportError(f"{path}: not a readable PNG/TIFF image")
    if img.ndim == 3 and img.shape[2] > 1 and not all(np.array_equal(img[..., 0], img[..., c])
                                                      for c in range(1, img.shape[2])):
        raise FrameImportError(f"{path}: a colour image ({img.shape[2]} channels): radiometric frames are "
                           f"single-channel 16-bit counts, not a colour-mapped picture")
    if img.ndim == 3:
        img = img[..., 0]
    if img.dtype != np.uint16:
        what = "8-bit" if img.dtype == np.uint8 else f"{img.dtype} "
        raise FrameImportError(f"{path}: {what} pixels: radiometric frames must be 16-bit counts "
                           f"(TemperatureLinear10mK/100mK); an 8-bit picture holds no temperatures")
    return img


def choose_scale(counts: np.ndarray, scale: float | None, fmt: str | None, path: Path) -> tuple[float, str]:
    """Kelvin per count: --scale, --format, else the one that puts the frame's median in 150-500 K."""
    if scale is not None:
        return scale, f"--scale {scale:g}"
    if fmt is not None:
        return FORMATS[fmt], f"--format {fmt}"
    med = float(np.median(counts[counts > 0])) if (counts > 0).any() else 0.0
    for name, s in FORMATS.items():
        if PLAUSIBLE_K[0] <= med * s <= PLAUSIBLE_K[1]:
            return s, f"auto: median count {med:.0f} x {s:g} K = {med * s:.1f} K ({name})"
    raise FrameImportError(f"{path}: cannot tell the counts' scale (median count {med:.0f} gives "
                       f"{med * 0.01:.1f} K at 10 mK or {med * 0.1:.1f} K at 100 mK); pass --scale or --format")


def phone_files(paths: list[Path]) -> list[Path]:
    from rig.drivers.phone import DropFolder
    out = []
    for p in paths:
        if p.is_dir():
            found = sorted((q for q in p.iterdir() if q.is_file() and DropFolder.wanted(q)),
                           key=lambda q: natural_key(q.name))
            if not found:
                raise FrameImportError(f"{p}: no phone videos (MOV/MP4) or photos (HEIC/JPEG) in this folder")
            out += found
        elif p.is_file():
            if not DropFolder.wanted(p):
                raise FrameImportError(f"{p}: not a phone video (MOV/MP4/M4V) or photo (HEIC/JPEG)")
            out.append(p)
        else:
            raise FrameImportError(f"{p}: no such file or folder")
    return out


@dataclass
class ImportResult:
    out: Path
    frames: int
    span_s: float
    phone: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    sync: dict = field(default_factory=dict)


def import_thermal(frames_dir, out, phone=(), scale: float | None = None, fmt: str | None = None,
                   timestamps: Path | None = None, fps: float | None = None, start: str | None = None,
                   progress=None) -> ImportResult:
    """Write the session `out` from a radiometric frame folder (and phone media). Raises
    FrameImportError (a ValueError naming the file) for malformed input; `out` is removed again
    when the import fails."""
    frames_dir, out = Path(frames_dir), Path(out)
    say = progress or (lambda msg: None)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"session folder {out} exists and is not empty")
    if fps is not None and timestamps is not None:
        raise FrameImportError("give --timestamps or --fps, not both")
    files = list_frames(frames_dir)
    times, time_source = frame_times(files, Path(timestamps) if timestamps else None, fps)
    order = np.argsort(times, kind="stable")
    files, times = [files[i] for i in order], times[order]
    same = np.flatnonzero(np.diff(times) <= 0)
    if len(same):
        k = int(same[0])
        raise FrameImportError(f"{files[k + 1]}: same timestamp as {files[k].name} ({times[k]:.6f} s); "
                           f"frames need distinct times")
    media = phone_files([Path(p) for p in phone])
    first = read_counts(files[0])
    scale_k, scale_from = choose_scale(first, scale, fmt, files[0])
    warnings: list[str] = []

    from rig.drivers.phone import PHOTO_SUFFIXES, probe_video
    videos = {}
    for p in media:
        if p.suffix.lower() not in PHOTO_SUFFIXES:
            say(f"phone {p.name}: reading frame times and motion")
            try:
                videos[p] = probe_video(p)
            except Exception as exc:              # PyAV's errors name no file
                raise FrameImportError(f"{p}: not a readable video ({' '.join(str(exc).split())})") from None

    # the session's host clock is Unix time; put the thermal timestamps on it
    absolute = bool(times[0] > ABSOLUTE_AFTER_S)
    if absolute:
        clock, t0 = "absolute timestamps (Unix time)", 0.0
        if start is not None:
            warnings.append("--start ignored: the timestamps are already absolute (Unix time)")
    elif start is not None:
        clock, t0 = f"--start {start}", parse_time(start, "--start") - times[0]
    elif videos:
        v = next(iter(videos.values()))
        begin = v.creation_unix_s if v.creation_unix_s is not None else \
            v.path.stat().st_mtime - v.duration_s
        clock, t0 = f"relative timestamps started with {v.path.name}", begin - times[0]
        warnings.append(f"relative thermal timestamps: assumed the thermal recording started with "
                        f"{v.path.name} (its creation date); if not, pass --start (the wall-clock time of "
                        f"the first thermal frame) or sync will not find the phone")
    else:
        clock, t0 = "relative timestamps from the first frame file's modification time", \
            files[0].stat().st_mtime - times[0]
    for v in videos.values():
        if v.creation_unix_s is None:
            warnings.append(f"{v.path.name} has no creation date: its start is taken as its modification "
                            f"time minus its duration")
    host_s = times + t0

    from rig.session import SessionWriter, open_session
    from rig.sync import synchronise_session
    created = not out.exists()
    meta = {"host_clock": {"monotonic_ns": 0, "realtime_ns": 0}, "simulated": False, "simulated_parts": [],
            "host": platform.node(), "created": dt.datetime.now(dt.timezone.utc).isoformat(),
            "thermal": {"source": f"import:{frames_dir.resolve()}", "tick_hz": 1e9, "device": None},
            "rgb": {"source": "import"},
            "imported": {"tool": "rig import thermal", "frames_dir": str(frames_dir.resolve()),
                         "frames": len(files), "timestamps": time_source, "clock": clock,
                         "scale_k": scale_k, "scale_from": scale_from,
                         "phone": [str(p.resolve()) for p in media], "warnings": warnings}}
    ir_format = next((n for n, s in FORMATS.items() if s == scale_k), None)
    writer = None
    try:
        writer = SessionWriter(out, meta)
        writer.add_event({"event": "epoch", "epoch": 0, "ir_format": ir_format, "scale_k": scale_k,
                          "host_ns": int(round(host_s[0] * 1e9))})
        h, w = first.shape
        prev, batch = None, []
        for k, (path, t) in enumerate(zip(files, host_s)):
            counts = first if k == 0 else read_counts(path)
            if counts.shape != (h, w):
                raise FrameImportError(f"{path}: {counts.shape[1]}x{counts.shape[0]} pixels, the first frame "
                                   f"{files[0].name} is {w}x{h}")
            ns = int(round(t * 1e9))
            th = thumbnail(counts)
            batch.append((np.ascontiguousarray(counts, "<u2").tobytes(), {
                "block_id": k + 1, "device_ts": ns, "host_ns": ns, "host_done_ns": ns, "width": w, "height": h,
                "pixel_format": "Mono16", "ir_format": ir_format, "scale_k": scale_k, "epoch": 0,
                "complete": True, "missing_packets": 0, "resent_packets": 0, "dropped_before": 0,
                "change": change_energy(prev, th), "source_file": path.name}))
            prev = th
            if len(batch) == BATCH:
                writer.add_thermal(batch)
                batch = []
            if (k + 1) % 200 == 0:
                say(f"thermal {k + 1}/{len(files)} frames")
        writer.add_thermal(batch)
        phone_out = []
        for p in media:
            st = p.stat()
            if p in videos:
                info = videos[p]
                frames = [{"frame": f["frame"], "pts": f["pts"], "pts_s": f["pts_s"], "motion": f["motion"]}
                          for f in info.frames]
                rel = writer.add_rgb_file(p, frames, {"kind": "video", "host_ns": st.st_mtime_ns,
                                                      **info.file_record()})
                phone_out.append({"file": rel, "kind": "video", "frames": len(frames)})
            else:
                rel = writer.add_rgb_file(p, [], {"kind": "photo", "host_ns": st.st_mtime_ns})
                phone_out.append({"file": rel, "kind": "photo", "frames": 0})
        if any(p["kind"] == "photo" for p in phone_out):
            warnings.append("photos are kept in rgb/ as `rig capture` keeps them; `recon prepare` uses the "
                            "phone videos of a session")
        sync = synchronise_session(open_session(out))
        writer.write_sync(sync.as_dict())
        writer.close({"imported": True, "sync_residual_ms": sync.residual_ms, "simulated": False,
                      "stats": {"thermal_frames": len(files), "rgb_frames": writer.n_rgb, "errors": []}})
        writer = None
    except BaseException:
        if writer is not None:
            try:
                writer.close()
            except OSError:
                pass
            if created:
                shutil.rmtree(out, ignore_errors=True)
            else:
                for child in out.iterdir():
                    shutil.rmtree(child) if child.is_dir() else child.unlink()
        raise
    return ImportResult(out, len(files), float(times[-1] - times[0]), phone_out, warnings,
                        {"method": sync.method, "rgb_offset_ms": sync.rgb_offset_ms,
                         "residual_ms": sync.residual_ms,
                         "files": [{"file": f.file, "offset_ms": round(f.offset_s * 1e3, 3),
                                    "correlation": round(f.correlation, 3)} for f in sync.files]})


EPILOG = """\
examples:
  rig import thermal ~/flir/take3 --out sessions/take3 --phone ~/iphone/IMG_0042.MOV
  rig import thermal frames/ --out sessions/t1 --timestamps frames.csv --format TemperatureLinear100mK \\
      --phone IMG_0001.MOV IMG_0002.MOV
  rig import thermal frames/ --out sessions/t2 --fps 30 --start 2026-05-01T12:34:56.200+02:00 --phone clips/
  rig info sessions/take3
  recon prepare sessions/take3 data/take3 --calibration rig_calibration.json

Frames: 16-bit single-channel PNG/TIFF counts (8-bit or colour-mapped pictures are refused).
Timestamps: --timestamps CSV (file,timestamp rows; seconds or ISO 8601; a header row is allowed),
else --fps (frames in natural name order), else from each file name: a date-time
YYYYMMDD[T_-]HHMMSS[.fff] (UTC), a number with a unit ending the name (123456us, 12.5ms, 3.25s),
or a Unix time of 10/13/16/19 digits (s/ms/us/ns).
Scale: --scale (kelvin per count) or --format, else whichever of 10 mK / 100 mK puts the first
frame's median between 150 and 500 K. Timestamps above 1e8 s are Unix time, the clock of the
phone's creation date; relative ones start at --start, else with the first phone video (a
warning says so). Writes a session as `rig capture` does (docs/rig.md); see docs/import.md.
Bad input: one line naming the file, exit 2.
"""


def register(sub) -> None:
    p = sub.add_parser("import", help="recordings made with other tools -> a session (see `rig import thermal`)",
                       description="Import recordings made with other tools.", formatter_class=HelpFormatter,
                       epilog="example:\n  rig import thermal FRAMES_DIR --out sessions/s1 --phone IMG_0001.MOV")
    kinds = p.add_subparsers(dest="kind", metavar="KIND")
    t = kinds.add_parser("thermal", help="a folder of radiometric 16-bit frames (+ phone media) -> a session",
                         description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter, epilog=EPILOG)
    t.add_argument("frames", type=Path, metavar="FRAMES_DIR", help="folder of 16-bit PNG/TIFF thermal frames")
    t.add_argument("--out", type=Path, required=True, help="session folder to create")
    t.add_argument("--phone", type=Path, nargs="+", action="extend", default=[], metavar="VIDEO_OR_PHOTOS",
                   help="phone videos (MOV/MP4), photos (HEIC/JPEG) or folders of them")
    g = t.add_mutually_exclusive_group()
    g.add_argument("--scale", type=positive_float, help="kelvin per count, e.g. 0.01 or 0.1; none given: auto")
    g.add_argument("--format", choices=list(FORMATS), help="FLIR IRFormat of the counts; none given: auto")
    g2 = t.add_mutually_exclusive_group()
    g2.add_argument("--timestamps", type=Path, metavar="CSV",
                    help="file,timestamp rows; none given: from the file names")
    g2.add_argument("--fps", type=positive_float, help="frame rate, when neither a CSV nor the names give times")
    t.add_argument("--start", metavar="TIME",
                   help="wall-clock time of the first frame for relative timestamps (Unix s or ISO 8601)")
    t.set_defaults(func=run)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def run(args) -> int:
    say = lambda msg: print(f"  {msg}", file=sys.stderr, flush=True)  # noqa: E731
    r = import_thermal(args.frames, args.out, args.phone, args.scale, args.format, args.timestamps, args.fps,
                       args.start, progress=say)
    for w in r.warnings:
        print(f"warning: {w}", file=sys.stderr)
    videos = [p for p in r.phone if p["kind"] == "video"]
    print(f"thermal  {r.frames} frames over {r.span_s:.2f} s")
    print(f"phone    {len(videos)} videos, {sum(p['frames'] for p in videos)} frames, "
          f"{len(r.phone) - len(videos)} photos")
    offs = ", ".join(f"{f['file']} {f['offset_ms']:+.1f} ms (r {f['correlation']:.2f})" for f in r.sync["files"])
    print(f"sync     {r.sync['method']}" + (f": {offs}" if offs else ""))
    print(r.out)
    return 0
