"""`rig calibrate`: RGB-thermal stereo calibration from a heated (or cooled) checkerboard.

A checkerboard printed on a plate and warmed (a heat lamp, a hair dryer from behind) or cooled
shows its squares in both cameras: the black squares absorb more and are warmer. Each view is
detected in both images (OpenCV `findChessboardCorners` + `cornerSubPix` first, which stays
unbiased on the heat-blurred thermal edges; `findChessboardCornersSB` as the fallback; thermal
images are stretched and inverted so warm squares look dark). Each camera is calibrated on its
own with the simplest distortion model (none, k1, k1 k2, k1 k2 p1 p2: the OPENCV model of the
dataset format) whose RMS is within 3 % of the fullest, since free terms trade off with focal
length on a narrow lens; then `stereoCalibrate` with both intrinsics fixed gives the extrinsic.
Input is either

- a session (`rig capture` while waving the board in front of the rig): thermal frames spread
  over the session, each with the RGB corners linearly interpolated between the two phone frames
  around its time (on the synced host clock), because the two cameras never expose together;
- a folder of pairs: `DIR/rgb/NAME.{png,jpg}` and `DIR/thermal/NAME.png` (16-bit counts or 8-bit),
  same NAME = same instant.

Result, `rig_calibration.json` (format "thermal4d-rig-calibration", version 1): `rgb` and
`thermal` lenses (`width height fx fy cx cy k1 k2 p1 p2`, pixel centres at +0.5 as in the dataset
format), `thermal_from_rgb` (4x4, metres: x_thermal = R x_rgb + t, OpenCV camera axes), `rms_px`
(per camera and stereo), `views`, `target`, `source`, `method`. Written into the session (or
folder) by default; `recon prepare` looks for it in the session, then in the session's parent
folder (one file for all sessions of a rig), unless `--calibration FILE` is given. Simulated
sessions also carry the simulator's true calibration, the documented fallback
(`simulated_calibration`).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from rig.cli_format import HelpFormatter

FORMAT = "thermal4d-rig-calibration"
VERSION = 1
CALIBRATION_FILE = "rig_calibration.json"
MIN_VIEWS = 6
MAX_RMS_PX = 1.0            # per-camera RMS above this: warn (bad detections or a moving board)
SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY


class CalibrationError(ValueError):
    """Calibration impossible or a calibration file unusable; the message says why and what to do."""


@dataclass(frozen=True)
class Lens:
    """Pinhole + OPENCV distortion of one camera, pixel centres at +0.5 (dataset convention)."""
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def scaled(self, width: int, height: int) -> "Lens":
        """The same lens sampled at another resolution (distortion is resolution-free)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy)

    def opencv_matrix(self) -> np.ndarray:
        """K (3, 3) in OpenCV's convention (integer pixel centres)."""
        return np.array([[self.fx, 0, self.cx - 0.5], [0, self.fy, self.cy - 0.5], [0, 0, 1.0]])

    def coefficients(self) -> np.ndarray:
        return np.array([self.k1, self.k2, self.p1, self.p2], np.float64)

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(np.abs(self.coefficients()) > 1e-9))


def lens_from_opencv(k: np.ndarray, dist: np.ndarray, width: int, height: int) -> Lens:
    d = np.zeros(4)
    d[:min(4, dist.size)] = np.ravel(dist)[:4]
    return Lens(int(width), int(height), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]) + 0.5,
                float(k[1, 2]) + 0.5, *(float(v) for v in d))


@dataclass
class RigCalibration:
    rgb: Lens
    thermal: Lens
    thermal_from_rgb: np.ndarray                 # (4, 4) metres, OpenCV camera axes
    rms_px: dict = field(default_factory=dict)   # "rgb", "thermal", "stereo"
    views: int = 0
    method: str = "checkerboard"                 # or "simulator" (known truth)
    source: str = ""
    target: dict | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def rgb_from_thermal(self) -> np.ndarray:
        return np.linalg.inv(self.thermal_from_rgb)

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.rgb_from_thermal[:3, 3]))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "method": self.method, "source": self.source,
                "rgb": asdict(self.rgb), "thermal": asdict(self.thermal),
                "thermal_from_rgb": np.asarray(self.thermal_from_rgb).tolist(),
                "baseline_m": round(self.baseline_m, 6), "rms_px": self.rms_px, "views": self.views,
                "target": self.target, "warnings": self.warnings}

    def save(self, path: str | Path) -> Path:
        """Write atomically (readers never see half a file)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        os.replace(tmp, path)
        return path


def calibration_from_dict(d: dict, where: str = "calibration") -> RigCalibration:
    if d.get("format") != FORMAT:
        raise CalibrationError(f"{where}: not a rig calibration (format {d.get('format')!r}, "
                               f"expected {FORMAT!r})")
    try:
        m = np.array(d["thermal_from_rgb"], np.float64)
        cal = RigCalibration(Lens(**d["rgb"]), Lens(**d["thermal"]), m, d.get("rms_px", {}),
                             int(d.get("views", 0)), d.get("method", "checkerboard"), d.get("source", ""),
                             d.get("target"), list(d.get("warnings", [])))
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: malformed rig calibration ({exc})") from None
    r = m[:3, :3] if m.shape == (4, 4) else np.zeros((3, 3))
    if m.shape != (4, 4) or not np.isfinite(m).all() or np.abs(r.T @ r - np.eye(3)).max() > 1e-4 \
            or np.linalg.det(r) <= 0:
        raise CalibrationError(f"{where}: thermal_from_rgb must be a rigid 4x4 transform")
    return cal


def load_calibration(path: str | Path) -> RigCalibration:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such calibration file") from None
    except ValueError as exc:
        raise CalibrationError(f"{path}: not valid JSON ({exc})") from None
    return calibration_from_dict(d, str(path))


def simulated_calibration(session) -> RigCalibration | None:
    """The simulator's true calibration recorded in a simulated session (None otherwise): in
    session.json from the start of the capture, or in closed.json's sim_truth at its end."""
    truth = (session.summary or {}).get("sim_truth") or []
    scene = (getattr(session, "meta", None) or {}).get("sim_scene") or next(
        (t.get("scene") for t in truth if t.get("scene")), None)
    if not scene or "thermal_from_rgb" not in scene:
        return None
    lens = [Lens(**{k: v for k, v in scene[key].items()}) for key in ("rgb_intrinsics", "thermal_intrinsics")]
    return RigCalibration(lens[0], lens[1], np.array(scene["thermal_from_rgb"]), method="simulator",
                          source=f"simulator truth ({scene.get('kind')}, seed {scene.get('seed')})")


def find_calibration(session_dir: str | Path, explicit: str | Path | None = None,
                     session=None) -> tuple[RigCalibration, str]:
    """The rig calibration for a session and where it came from: `explicit`, else
    SESSION/rig_calibration.json, else the parent folder's, else (simulated sessions) the
    simulator's truth. Raises CalibrationError with what to do."""
    session_dir = Path(session_dir)
    if explicit is not None:
        return load_calibration(explicit), str(explicit)
    for candidate in (session_dir / CALIBRATION_FILE, session_dir.parent / CALIBRATION_FILE):
        if candidate.is_file():
            return load_calibration(candidate), str(candidate)
    if session is not None and (cal := simulated_calibration(session)) is not None:
        return cal, "simulator truth (no rig_calibration.json found; simulated session)"
    raise CalibrationError(
        f"no rig calibration for {session_dir}: looked for {session_dir / CALIBRATION_FILE} and "
        f"{session_dir.parent / CALIBRATION_FILE}. Capture the heated checkerboard in front of the rig "
        f"and run `rig calibrate CALIB_SESSION --out {session_dir.parent / CALIBRATION_FILE}`, or pass "
        f"--calibration FILE")


# -- detection --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Target:
    pattern: tuple[int, int] = (8, 6)      # inner corners (columns, rows)
    square_m: float = 0.016

    def object_points(self) -> np.ndarray:
        """(N, 3) float32 corners on the board plane, row by row (cv2 order)."""
        i, j = np.meshgrid(np.arange(self.pattern[0]), np.arange(self.pattern[1]))
        return np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], 1).astype(np.float32) * self.square_m


def thermal_to_u8(kelvin: np.ndarray) -> np.ndarray:
    """(H, W) kelvin -> uint8 with warm = dark (a heated board then looks like the printed one);
    1st-99th percentile stretch; unmeasured (0 / NaN) pixels become mid-grey."""
    k = np.asarray(kelvin, np.float64)
    valid = np.isfinite(k) & (k > 0)
    if not valid.any():
        return np.full(k.shape, 128, np.uint8)
    lo, hi = np.percentile(k[valid], [1, 99])
    x = np.where(valid, (k - lo) / max(hi - lo, 1e-6), 0.5)
    return (255 * (1 - np.clip(x, 0, 1))).astype(np.uint8)


def canonical_order(corners: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """Resolve the 180-degree ambiguity of a symmetric board: rows run towards +x in the image
    (towards +y if the board stands on end), the same rule for both cameras of a rig."""
    c = corners.reshape(-1, 2)
    first_row = c[pattern[0] - 1] - c[0]
    d = first_row[0] if abs(first_row[0]) >= abs(first_row[1]) else first_row[1]
    return c[::-1].copy() if d < 0 else c


def _refine(img: np.ndarray, corners: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """Sub-pixel corners; the search window is kept under half the smallest square."""
    c = corners.reshape(-1, 2)
    grid = c.reshape(pattern[1], pattern[0], 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
                  np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    half = int(np.clip(spacing * 0.4, 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    return cv2.cornerSubPix(img, corners.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1), criteria)


def detect_corners(gray: np.ndarray, pattern: tuple[int, int], fast: bool = False) -> np.ndarray | None:
    """Inner corners (N, 2) float32 in OpenCV pixel coordinates, canonical order; None if the
    whole board is not found. Either polarity (the board's or its negative) is accepted.
    The classic detector with cornerSubPix comes first: on a simulated heated board it lands
    0.02 px from the truth in thermal where the sector-based detector is biased by 0.5 px
    (conduction blurs the edges); the sector-based one is the fallback (more robust, slower;
    skipped with `fast`, which also rejects board-free images quickly, for scanning videos)."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | (cv2.CALIB_CB_FAST_CHECK if fast else 0)
    for img in (gray, 255 - gray):
        found, corners = cv2.findChessboardCorners(img, pattern, flags=flags)
        if found:
            return canonical_order(_refine(img, corners, pattern), pattern).astype(np.float32)
    if fast:
        return None
    for img in (gray, 255 - gray):
        found, corners = cv2.findChessboardCornersSB(img, pattern, flags=SB_FLAGS)
        if found:
            return canonical_order(corners, pattern).astype(np.float32)
    return None


def rgb_to_gray(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


@dataclass
class View:
    name: str
    rgb: np.ndarray          # (N, 2) OpenCV pixel coordinates
    thermal: np.ndarray      # (N, 2)


@dataclass
class ViewSet:
    views: list[View]
    rgb_size: tuple[int, int]         # (w, h)
    thermal_size: tuple[int, int]
    tried: int                        # candidate views examined
    found_rgb: int
    found_thermal: int
    source: str


# -- sources ----------------------------------------------------------------------------------------

def frame_times(session, sync) -> tuple[np.ndarray, np.ndarray]:
    """Host-clock seconds of every thermal record (N,) and RGB record (M,) of a session (NaN for
    RGB frames of files sync could not place)."""
    from rig.sync import ClockFit
    tick = session.meta.get("thermal", {}).get("tick_hz", 1e9)
    th = session.thermal
    if sync.thermal_clock and all(r.get("device_ts") for r in th):
        t_th = ClockFit(**sync.thermal_clock)(np.array([r["device_ts"] for r in th], float) / tick)
    else:
        t_th = np.array([r["host_ns"] for r in th], float) / 1e9
    files = {f.file: f for f in sync.files if np.isfinite(f.offset_s)}
    t_rgb = np.full(len(session.rgb), np.nan)
    for k, r in enumerate(session.rgb):
        fs = files.get(r["file"])
        if fs is not None:
            t_rgb[k] = float(sync.rgb_host_s(r["file"], np.array([fs.nominal_start_s + r["pts_s"]]))[0])
    return np.asarray(t_th, float), t_rgb


def session_views(path: str | Path, target: Target, max_views: int = 30, progress=None) -> ViewSet:
    """Views of the target in a session: thermal frames spread over it, each with RGB corners
    interpolated to its time from the phone frames just before and after."""
    from rig.session import open_session
    from rig.sync import synchronise_session
    session = open_session(path)
    sync = synchronise_session(session)
    if sync.method == "none":
        raise CalibrationError(f"{path}: thermal and phone frames could not be synchronised "
                               f"(no phone files or too few frames); recapture with both cameras running")
    t_th, t_rgb = frame_times(session, sync)
    order = np.argsort(np.where(np.isfinite(t_rgb), t_rgb, np.inf))
    order = order[np.isfinite(t_rgb[order])]
    inside = [i for i in range(len(t_th)) if session.thermal[i]["complete"] and len(order)
              and t_rgb[order[0]] <= t_th[i] < t_rgb[order[-1]]]
    picks = [inside[k] for k in np.unique(np.linspace(0, len(inside) - 1, max_views).round().astype(int))] \
        if inside else []
    wanted = {}                                    # rgb record index -> needed
    brackets = {}
    for i in picks:
        j = int(np.searchsorted(t_rgb[order], t_th[i], side="right"))
        a, b = int(order[j - 1]), int(order[j])
        brackets[i] = (a, b, (t_th[i] - t_rgb[a]) / max(t_rgb[b] - t_rgb[a], 1e-9))
        wanted[a] = wanted[b] = True
    rgb_corners, rgb_size = {}, None
    for frame in session.iter_rgb():
        if frame.index in wanted:
            rgb_size = (frame.image.shape[1], frame.image.shape[0])
            rgb_corners[frame.index] = detect_corners(rgb_to_gray(frame.image), target.pattern)
    views, found_rgb, found_th, th_size = [], 0, 0, None
    for n, i in enumerate(picks):
        f = session.thermal_frame(i)
        th_size = (f.counts.shape[1], f.counts.shape[0])
        c_th = detect_corners(thermal_to_u8(f.kelvin()), target.pattern)
        a, b, w = brackets[i]
        ca, cb = rgb_corners.get(a), rgb_corners.get(b)
        found_rgb += ca is not None and cb is not None
        found_th += c_th is not None
        if c_th is not None and ca is not None and cb is not None:
            views.append(View(f"thermal#{i}", ((1 - w) * ca + w * cb).astype(np.float32), c_th))
        if progress:
            progress(n + 1, len(picks), len(views))
    return ViewSet(views, rgb_size or (0, 0), th_size or (0, 0), len(picks), found_rgb, found_th,
                   f"session {path}")


RGB_SUFFIXES = (".png", ".jpg", ".jpeg")


def folder_views(path: str | Path, target: Target, progress=None) -> ViewSet:
    """Views of the target in DIR/rgb/NAME.* + DIR/thermal/NAME.png pairs."""
    path = Path(path)
    rgb_files = {p.stem: p for p in sorted((path / "rgb").glob("*")) if p.suffix.lower() in RGB_SUFFIXES}
    th_files = {p.stem: p for p in sorted((path / "thermal").glob("*.png"))}
    names = sorted(set(rgb_files) & set(th_files))
    if not names:
        raise CalibrationError(f"{path}: no image pairs; expected rgb/NAME.png|jpg and thermal/NAME.png "
                               f"with the same NAME (found {len(rgb_files)} RGB, {len(th_files)} thermal)")
    views, found_rgb, found_th, rgb_size, th_size = [], 0, 0, None, None
    for n, name in enumerate(names):
        rgb = cv2.imread(str(rgb_files[name]), cv2.IMREAD_COLOR)
        th = cv2.imread(str(th_files[name]), cv2.IMREAD_UNCHANGED)
        if rgb is None or th is None or th.ndim != 2:
            raise CalibrationError(f"{path}: pair {name} is unreadable (thermal must be one channel)")
        rgb_size, th_size = (rgb.shape[1], rgb.shape[0]), (th.shape[1], th.shape[0])
        c_rgb = detect_corners(cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY), target.pattern)
        c_th = detect_corners(thermal_to_u8(th.astype(np.float64)), target.pattern)
        found_rgb += c_rgb is not None
        found_th += c_th is not None
        if c_rgb is not None and c_th is not None:
            views.append(View(name, c_rgb, c_th))
        if progress:
            progress(n + 1, len(names), len(views))
    return ViewSet(views, rgb_size, th_size, len(names), found_rgb, found_th, f"folder {path}")


# -- calibration ------------------------------------------------------------------------------------

_FIX_ALL = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
DISTORTION_MODELS = (("none", _FIX_ALL | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2),
                     ("k1", _FIX_ALL | cv2.CALIB_FIX_K2),
                     ("k1 k2", _FIX_ALL),
                     ("k1 k2 p1 p2", cv2.CALIB_FIX_K3))
SIMPLER_MODEL_RMS = 1.03     # a simpler lens model is kept if its RMS is within 3 % of the fullest


def calibrate_camera(obj: list, pts: list, size: tuple[int, int]) -> tuple[float, np.ndarray, np.ndarray, str]:
    """Intrinsics of one camera with the simplest distortion model that explains the corners:
    free distortion terms trade off with focal length and principal point when the board covers
    only the middle of a narrow field of view (measured: k2 = 19 and a 0.45 deg extrinsic error
    where the true lens had none). -> (RMS px, K, dist (5,), model name)."""
    fits = []
    for name, flags in DISTORTION_MODELS:
        rms, k, dist, _, _ = cv2.calibrateCamera(obj, pts, size, None, None, flags=flags)
        fits.append((rms, k, dist, name))
    best = min(f[0] for f in fits)
    return next(f for f in fits if f[0] <= best * SIMPLER_MODEL_RMS)


def calibrate_views(vs: ViewSet, target: Target) -> RigCalibration:
    """Intrinsics of each camera, then the extrinsic with both fixed. Raises CalibrationError when
    the target was found in too few views."""
    if len(vs.views) < MIN_VIEWS:
        raise CalibrationError(
            f"calibration target not found in enough views: {len(vs.views)} usable of {vs.tried} "
            f"(board found in {vs.found_rgb} RGB and {vs.found_thermal} thermal images; need {MIN_VIEWS}). "
            f"Recapture with the whole {target.pattern[0] + 1}x{target.pattern[1] + 1}-square board in "
            f"both views, tilted in several directions, moved slowly, and heated (or cooled) so its "
            f"squares differ by several kelvin in the thermal image")
    obj = [target.object_points() for _ in vs.views]
    rgb_pts = [v.rgb.reshape(-1, 1, 2) for v in vs.views]
    th_pts = [v.thermal.reshape(-1, 1, 2) for v in vs.views]
    rms_rgb, k_rgb, d_rgb, model_rgb = calibrate_camera(obj, rgb_pts, vs.rgb_size)
    rms_th, k_th, d_th, model_th = calibrate_camera(obj, th_pts, vs.thermal_size)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    rms_st, *_, r, t, _, _ = cv2.stereoCalibrate(obj, rgb_pts, th_pts, k_rgb, d_rgb, k_th, d_th, vs.rgb_size,
                                                 criteria=criteria, flags=cv2.CALIB_FIX_INTRINSIC)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t.ravel()
    cal = RigCalibration(lens_from_opencv(k_rgb, d_rgb, *vs.rgb_size),
                         lens_from_opencv(k_th, d_th, *vs.thermal_size), m,
                         {"rgb": round(rms_rgb, 4), "thermal": round(rms_th, 4), "stereo": round(rms_st, 4)},
                         len(vs.views), "checkerboard", vs.source,
                         {"pattern": list(target.pattern), "square_m": target.square_m,
                          "distortion_terms": {"rgb": model_rgb, "thermal": model_th}})
    for cam, rms in cal.rms_px.items():
        if rms > MAX_RMS_PX:
            cal.warnings.append(f"{cam} RMS reprojection error {rms:.2f} px > {MAX_RMS_PX} px: blurred or "
                                f"moving views; recapture holding the board still")
    return cal


def calibrate(source: str | Path, target: Target | None = None, max_views: int = 30,
              progress=None) -> RigCalibration:
    """Calibrate from a session folder or a folder of image pairs."""
    target = target or Target()
    source = Path(source)
    if (source / "session.json").is_file():
        vs = session_views(source, target, max_views, progress)
    elif (source / "rgb").is_dir() and (source / "thermal").is_dir():
        vs = folder_views(source, target, progress)
    else:
        raise CalibrationError(f"{source}: neither a session (session.json) nor a folder with rgb/ and "
                               f"thermal/ image pairs")
    return calibrate_views(vs, target)


# -- CLI --------------------------------------------------------------------------------------------

def _pattern(text: str) -> tuple[int, int]:
    try:
        c, r = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"pattern must look like 8x6 (inner corners), got {text!r}") from None
    if c < 2 or r < 2:
        raise argparse.ArgumentTypeError("a board needs at least 2x2 inner corners")
    return c, r


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate", help="RGB-thermal stereo calibration from a heated checkerboard",
        description=__doc__, formatter_class=HelpFormatter,
        epilog="examples:\n"
               "  rig capture --sim-scene calibration --sim-keyframes 30 --sim-render-scale 0.5 \\\n"
               "              --duration 8 --out sessions/calib     # simulated rig, heated board\n"
               "  rig calibrate sessions/calib                         # -> sessions/calib/rig_calibration.json\n"
               "  rig calibrate sessions/calib --out sessions/rig_calibration.json   # for every session\n"
               "  rig calibrate pairs/ --pattern 8x6 --square 0.016     # pairs/rgb/*.png + pairs/thermal/*.png")
    p.add_argument("source", metavar="SESSION_OR_IMAGES",
                   help="session folder, or folder with rgb/NAME.png|jpg and thermal/NAME.png pairs")
    p.add_argument("--out", type=Path, help="where to write (default: SOURCE/rig_calibration.json)")
    p.add_argument("--pattern", type=_pattern, default=(8, 6), help="inner corners, columns x rows")
    p.add_argument("--square", type=float, default=0.016, help="square size in metres")
    p.add_argument("--max-views", type=int, default=30, help="session: thermal frames examined")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")
    p.set_defaults(func=main)


def main(args) -> int:
    if args.square <= 0 or args.max_views < 1:
        print("rig calibrate: --square must be positive and --max-views >= 1", file=sys.stderr)
        return 2

    def progress(done: int, total: int, usable: int) -> None:
        print(f"\r  views {done}/{total}, usable {usable}", end="\n" if done == total else "",
              file=sys.stderr, flush=True)

    try:
        cal = calibrate(args.source, Target(args.pattern, args.square), args.max_views, progress)
    except (CalibrationError, FileNotFoundError) as exc:
        print(f"rig calibrate: {exc}", file=sys.stderr)
        return 2
    out = cal.save(args.out or Path(args.source) / CALIBRATION_FILE)
    if args.json:
        print(json.dumps(cal.to_dict(), indent=1))
    r = np.degrees(np.arccos(np.clip((np.trace(cal.thermal_from_rgb[:3, :3]) - 1) / 2, -1, 1)))
    print(f"{cal.views} views; RMS px rgb {cal.rms_px['rgb']:.3f}, thermal {cal.rms_px['thermal']:.3f}, "
          f"stereo {cal.rms_px['stereo']:.3f}; baseline {cal.baseline_m * 100:.2f} cm, rotation {r:.2f} deg")
    print(f"  rgb     f {cal.rgb.fx:.1f}/{cal.rgb.fy:.1f} c {cal.rgb.cx:.1f},{cal.rgb.cy:.1f} "
          f"k {cal.rgb.k1:+.4f} {cal.rgb.k2:+.4f}")
    print(f"  thermal f {cal.thermal.fx:.1f}/{cal.thermal.fy:.1f} c {cal.thermal.cx:.1f},{cal.thermal.cy:.1f} "
          f"k {cal.thermal.k1:+.4f} {cal.thermal.k2:+.4f}")
    for w in cal.warnings:
        print(f"  warning: {w}", file=sys.stderr)
    print(out)
    return 0
