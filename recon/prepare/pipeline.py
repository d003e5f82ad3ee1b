"""`prepare_session`: a rig session -> a prepared dataset (shared/FORMATS.md) with poses.

Steps: find the rig calibration; sync and pair thermal with phone frames; pick one sharp phone
frame per time bin; recover their poses and sparse points with pycolmap; check the result
(registered fraction, reprojection error); find the metric scale; give each thermal frame the
RGB pose interpolated to its own time composed with the calibrated extrinsic; write images,
poses, intrinsics (OPENCV model where a lens has distortion: `recon.data` undistorts on load),
`points3d.ply` and `prepare_report.json`. Whatever cannot be trusted stops the run with a
`PrepareError` that says what was measured and what to recapture; the report is written either way.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from recon.data import Distortion, Frame, c2w_opencv_to_opengl, write_dataset
from recon.prepare.frames import PrepareError, Selected, Timeline, select_frames, session_timeline
from recon.prepare.poses import interpolate_pose, path_jitter_deg
from recon.prepare.report import Report
from recon.prepare.scale import DEPTH_RANGE_M, ScaleEstimate, scale_from_target, scale_from_truth
from recon.prepare.simtruth import session_truth
from recon.sfm import SfmError, SfmOptions, SfmResult, diagnose, run_sfm
from rig.calibrate import (CalibrationError, Lens, RigCalibration, Target, detect_corners, find_calibration)
from rig.session import open_session

THERMAL_SCALE_K = 0.01          # dataset counts: TemperatureLinear10mK (lossless for 10 / 100 mK input)
LOW_LIGHT = 0.3                 # median grey level below which frames count as dark
JITTER_WARN_DEG = 0.3           # median path jitter above which poses are called noisy
MIN_DISTORTION_PX = 0.25        # a lens whose distortion moves no pixel further is written as PINHOLE
REPORT_FILE = "prepare_report.json"


@dataclass
class PrepareOptions:
    calibration: Path | None = None      # rig_calibration.json (default: found beside the session)
    frames: int = 80                     # time steps picked over the session (one RGB + one thermal each)
    test_every: int = 8                  # every n-th time step is held out as test; 0: none
    scale: float | None = None           # metres per SfM unit (default: checkerboard, else thermal)
    downscale: int = 1                   # integer factor applied to the written images
    matching: str = "sequential"         # pycolmap pairing: "sequential" (+ loop closure) or "exhaustive"
    mask_box: tuple[float, float, float, float] | None = None   # x0 y0 x1 y1 fractions, e.g. the sync lamp
    min_registered: float = 0.8          # refuse below this fraction of registered frames
    max_reprojection_px: float = 2.0     # refuse above this mean reprojection error
    max_jitter_deg: float = 1.0          # refuse above this median path jitter (see path_jitter_deg)
    refine_intrinsics: bool = False      # let bundle adjustment refine the calibrated phone intrinsics
    max_image_size: int = 1600
    keep_work: bool = False              # keep OUT/.work (SfM images, database, model)
    threads: int = 2
    seed: int = 0

    def __post_init__(self):
        if self.frames < 3 or self.downscale < 1 or self.test_every < 0:
            raise ValueError("frames must be >= 3, downscale >= 1, test_every >= 0")
        if self.scale is not None and not self.scale > 0:
            raise ValueError(f"scale must be positive metres per SfM unit, got {self.scale}")
        if self.calibration is not None:
            self.calibration = Path(self.calibration)


def _lamp_box(session, options: PrepareOptions) -> tuple[float, ...] | None:
    if options.mask_box is not None:
        return tuple(options.mask_box)
    for t in (session.summary or {}).get("sim_truth") or []:
        if (t.get("scene") or {}).get("lamp_box"):
            return tuple(t["scene"]["lamp_box"])
    return session.meta.get("lamp_box")


def _box_pixels(box, w: int, h: int) -> tuple[slice, slice]:
    x0, y0, x1, y1 = box
    return slice(int(y0 * h), int(np.ceil(y1 * h))), slice(int(x0 * w), int(np.ceil(x1 * w)))


def _sfm_inputs(selected: list[Selected], work: Path, box) -> tuple[list[str], Path | None]:
    images = work / "images"
    images.mkdir(parents=True)
    names = [f"{k:06d}.png" for k in range(len(selected))]
    for name, s in zip(names, selected):
        cv2.imwrite(str(images / name), cv2.cvtColor(s.image, cv2.COLOR_RGB2BGR))
    if box is None:
        return names, None
    masks = work / "masks"
    masks.mkdir()
    h, w = selected[0].image.shape[:2]
    mask = np.full((h, w), 255, np.uint8)
    mask[_box_pixels(box, w, h)] = 0
    for name in names:
        cv2.imwrite(str(masks / f"{name}.png"), mask)
    return names, masks


def _colmap_camera(lens: Lens, w: int, h: int) -> tuple[str, str]:
    """Initial COLMAP camera from the calibrated phone lens at the video's size."""
    lens = lens.scaled(w, h)
    if lens.has_distortion:
        return "OPENCV", ",".join(f"{v:.8g}" for v in (lens.fx, lens.fy, lens.cx, lens.cy, lens.k1, lens.k2,
                                                           lens.p1, lens.p2))
    return "SIMPLE_RADIAL", f"{(lens.fx + lens.fy) / 2:.8g},{lens.cx:.8g},{lens.cy:.8g},0"


def _max_distortion_px(fx: float, fy: float, cx: float, cy: float, w: int, h: int, d: np.ndarray) -> float:
    """Largest displacement (px) the k1 k2 p1 p2 model applies at the image corners."""
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], np.float64)
    x, y = (corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy
    r2 = x * x + y * y
    radial = d[0] * r2 + d[1] * r2 * r2
    dx = x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x)
    dy = y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y
    return float(np.max(np.hypot(dx * fx, dy * fy)))


def _intrinsics(fx, fy, cx, cy, w, h, coeffs, factor: int) -> tuple[tuple, Distortion | None]:
    """Intrinsics after downscaling by `factor` and the lens model to store (None = pinhole)."""
    k = (fx / factor, fy / factor, cx / factor, cy / factor)
    if _max_distortion_px(fx, fy, cx, cy, w, h, np.asarray(coeffs)) < MIN_DISTORTION_PX:
        return k, None
    return k, Distortion(*k, *(float(v) for v in coeffs))


def _downscale_rgb(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    h, w = img.shape[:2]
    return cv2.resize(img, (w // f, h // f), interpolation=cv2.INTER_AREA)


def _downscale_counts(counts: np.ndarray, f: int) -> np.ndarray:
    """uint16 counts averaged over f x f blocks; a block with any unmeasured (0) pixel is 0."""
    if f == 1:
        return counts
    h, w = counts.shape[0] // f * f, counts.shape[1] // f * f
    blocks = counts[:h, :w].reshape(h // f, f, w // f, f).astype(np.float64)
    out = np.round(blocks.mean(axis=(1, 3)))
    out[(blocks == 0).any(axis=(1, 3))] = 0
    return out.astype(np.uint16)


def _thermal_counts(frame) -> np.ndarray:
    """Kelvin of a session thermal frame as dataset counts (0 = no measurement)."""
    kelvin = frame.kelvin()
    counts = np.clip(np.round(kelvin / THERMAL_SCALE_K), 0, 65535).astype(np.uint16)
    counts[~np.isfinite(kelvin) | (frame.counts == 0)] = 0
    return counts


def _observed(result: SfmResult, names: list[str]) -> dict[str, np.ndarray]:
    seen: dict[str, list[int]] = {n: [] for n in names}
    for i, track in enumerate(result.tracks):
        for n in set(track):
            seen[n].append(i)
    return {n: np.array(v, np.int64) for n, v in seen.items()}


def _median_depth(result: SfmResult, observed: dict[str, np.ndarray]) -> float:
    depths = []
    for n, c2w in result.c2w.items():
        idx = observed[n]
        if len(idx):
            w2c = np.linalg.inv(c2w)
            depths.append(np.median((result.points_xyz[idx] @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]))
    return float(np.median(depths))


def _find_scale(options: PrepareOptions, session, result: SfmResult, names, selected, registered,
                cal: RigCalibration, report: Report) -> ScaleEstimate:
    """--scale, else the checkerboard in view, else (simulated sessions) the simulator's truth."""
    if options.scale is not None:
        return ScaleEstimate(options.scale, "explicit")
    target = Target(tuple((cal.target or {}).get("pattern", (8, 6))), (cal.target or {}).get("square_m", 0.016))
    corners = {}
    for n, s in zip(names, selected):
        if n in registered:
            c = detect_corners(cv2.cvtColor(s.image, cv2.COLOR_RGB2GRAY), target.pattern, fast=True)
            if c is not None:
                corners[n] = c
    cams = {n: result.cameras[n] for n in corners}
    est = scale_from_target(corners, result.c2w, {n: c.opencv_matrix() for n, c in cams.items()},
                            {n: c.coefficients() for n, c in cams.items()}, target.pattern, target.square_m)
    if est is not None and est.metres_per_unit is not None:
        return est
    reason = (est.detail["reason"] if est is not None else
              f"the {target.pattern[0] + 1}x{target.pattern[1] + 1}-square checkerboard was found in "
              f"{len(corners)} registered frames (need 3)")
    truth = session_truth(session)
    if truth is not None:
        k = [names.index(n) for n in registered]
        report.note(f"metric scale: the simulator's true camera path (documented fallback for simulated "
                    f"sessions; {reason})")
        return scale_from_truth(np.stack([result.c2w[names[i]] for i in k]),
                                np.stack([truth.rgb_pose(session.rgb[selected[i].pair.rgb_index]) for i in k]))
    return ScaleEstimate(None, "none", {"reason": reason})


def prepare_session(session_dir: str | Path, out_dir: str | Path, progress=print, **options) -> Path:
    """Turn a rig session into a prepared dataset in `out_dir`; returns out_dir/transforms.json.
    Options: the fields of PrepareOptions. Raises PrepareError (with advice) when the result could
    not be trusted; `out_dir/prepare_report.json` is written in both cases."""
    opts = PrepareOptions(**options)
    say = progress or (lambda msg: None)
    out = Path(out_dir)
    if out.exists() and any(p.name != REPORT_FILE for p in out.iterdir()):
        raise PrepareError(f"{out} exists and is not empty; choose a new output folder")
    out.mkdir(parents=True, exist_ok=True)
    report = Report(str(session_dir), options={k: (str(v) if isinstance(v, Path) else v)
                                               for k, v in asdict(opts).items()})
    try:
        path = _prepare(Path(session_dir), out, opts, report, say)
        report.finish("ok")
        return path
    except (PrepareError, SfmError, CalibrationError) as exc:
        report.finish("failed", str(exc))
        raise PrepareError(str(exc)) from exc
    finally:
        report.write(out / REPORT_FILE)
        if not opts.keep_work:
            shutil.rmtree(out / ".work", ignore_errors=True)


def _prepare(session_dir: Path, out: Path, opts: PrepareOptions, report: Report, say) -> Path:
    t_start = time.perf_counter()
    try:
        session = open_session(session_dir)
    except (FileNotFoundError, ValueError) as exc:
        raise PrepareError(str(exc)) from None
    if not session.closed:
        report.warn("the session has no closed.json (still capturing, or it crashed): using the frames "
                    "committed so far")
    cal, cal_source = find_calibration(session_dir, opts.calibration, session)
    report.calibration = {"source": cal_source, "method": cal.method, "baseline_m": round(cal.baseline_m, 5),
                          "rms_px": cal.rms_px}
    if cal.method == "simulator":
        report.note("rig calibration: the simulator's true calibration (documented fallback for simulated "
                    "sessions without rig_calibration.json)")

    timeline = session_timeline(session)
    report.sync = timeline.sync
    say(f"{len(timeline.pairs)} thermal/phone pairs over {timeline.t1 - timeline.t0:.1f} s "
        f"(sync {timeline.sync['method']})")
    selected = select_frames(session, timeline, opts.frames, say)
    brightness = float(np.median([s.brightness for s in selected]))
    report.frames.update(paired=len(timeline.pairs), selected=len(selected),
                         median_brightness=round(brightness, 4),
                         median_sharpness=round(float(np.median([s.sharpness for s in selected])), 2))
    low_light = brightness < LOW_LIGHT
    if low_light:
        report.warn(f"low light: median grey level {brightness:.2f} (< {LOW_LIGHT}) in the phone frames")

    box = _lamp_box(session, opts)
    work = out / ".work"
    shutil.rmtree(work, ignore_errors=True)
    names, mask_dir = _sfm_inputs(selected, work, box)
    h_rgb, w_rgb = selected[0].image.shape[:2]
    model, params = _colmap_camera(cal.rgb, w_rgb, h_rgb)
    sfm_opts = SfmOptions(matching=opts.matching, camera_model=model, camera_params=params, mask_dir=mask_dir,
                          refine_intrinsics=opts.refine_intrinsics, max_image_size=opts.max_image_size,
                          num_threads=opts.threads, seed=opts.seed)
    say(f"pycolmap on {len(names)} frames ({opts.matching} matching, {opts.threads} threads)")
    try:
        result = run_sfm(work / "images", names, work / "sfm", sfm_opts, say)
    except SfmError as exc:
        report.sfm = exc.stats
        raise PrepareError(_with_light_hint(str(exc), low_light, brightness)) from None
    report.sfm = result.stats
    registered = [n for n in names if n in result.c2w]
    fraction = len(registered) / len(names)
    report.frames["registered"] = len(registered)
    unregistered = _spans([selected[k].pair.rgb_s - timeline.t0 for k, n in enumerate(names) if n not in result.c2w])
    if fraction < opts.min_registered:
        raise PrepareError(_with_light_hint(
            f"pose recovery registered {len(registered)}/{len(names)} frames ({fraction:.0%} < "
            f"{opts.min_registered:.0%}); unregistered at {unregistered} s. "
            + diagnose(result.stats, len(registered), len(names)), low_light, brightness))
    if len(registered) < len(names):
        report.warn(f"{len(names) - len(registered)} of {len(names)} frames did not register (at {unregistered} s; "
                    f"a moving object filling the view, blur or a fast turn): the dataset keeps the "
                    f"{len(registered)} registered time steps")
    err = result.stats["mean_reprojection_error_px"]
    if err > opts.max_reprojection_px:
        raise PrepareError(f"mean reprojection error {err:.2f} px > {opts.max_reprojection_px} px: the "
                           f"reconstruction is inconsistent (rolling shutter, motion blur, moving objects "
                           f"matched as static); recapture moving slower")

    reg_idx = [names.index(n) for n in registered]
    reg_times = np.array([selected[k].pair.rgb_s for k in reg_idx])
    reg_c2w = np.stack([result.c2w[names[k]] for k in reg_idx])
    jitter = path_jitter_deg(reg_times, reg_c2w)
    if len(jitter):
        med = float(np.median(jitter))
        report.sfm.update(path_jitter_deg_median=round(med, 4), path_jitter_deg_max=round(float(jitter.max()), 4))
        if med > opts.max_jitter_deg:
            raise PrepareError(_with_light_hint(
                f"the recovered camera path is not smooth: a pose differs by {med:.2f} deg (median) from "
                f"the one interpolated from its neighbours (> {opts.max_jitter_deg} deg), so the poses are "
                f"unreliable (noise, blur, few features: median {result.stats['features_median']:.0f} per "
                f"frame). Recapture with more light and slower motion", low_light, brightness))
        if med > JITTER_WARN_DEG:
            report.warn(f"noisy poses: path jitter {med:.2f} deg median (> {JITTER_WARN_DEG}); expect blurred "
                        f"thermal alignment" + (" (low light)" if low_light else ""))

    # thermal camera and poses in SfM units, then the metric scale
    th0 = session.thermal_frame(selected[0].pair.thermal_index)
    h_th, w_th = th0.counts.shape
    thermal_lens = cal.thermal.scaled(w_th, h_th)
    if abs(cal.thermal.width / cal.thermal.height - w_th / h_th) > 0.01:
        raise PrepareError(f"the calibration's thermal image is {cal.thermal.width}x{cal.thermal.height} but "
                           f"the session's is {w_th}x{h_th}: calibrate this camera mode")
    at_thermal = {n: interpolate_pose(reg_times, reg_c2w, selected[k].pair.thermal_s)
                  for n, k in zip(registered, reg_idx)}
    depth_units = _median_depth(result, _observed(result, names))
    scale = _find_scale(opts, session, result, names, selected, registered, cal, report)
    report.scale = {"method": scale.method, "metres_per_unit": scale.metres_per_unit,
                    **scale.detail}
    if scale.metres_per_unit is None:
        raise PrepareError(
            f"metric scale unknown ({scale.detail.get('reason', 'no estimate')}): the thermal poses need the "
            f"{cal.baseline_m * 100:.1f} cm RGB-thermal baseline in SfM units. Recapture with the "
            f"calibration checkerboard (flat, whole, in view of the phone) for a few seconds, or pass "
            f"--scale METRES_PER_UNIT")
    depth_m = depth_units * scale.metres_per_unit
    report.scale["median_depth_m"] = round(depth_m, 4)
    if not DEPTH_RANGE_M[0] <= depth_m <= DEPTH_RANGE_M[1]:
        raise PrepareError(f"metric scale implausible: the scene would be {depth_m:.3f} m from the camera "
                           f"(expected {DEPTH_RANGE_M[0]}-{DEPTH_RANGE_M[1]} m); check --scale or the target size")

    frames = _dataset_frames(session, timeline, selected, names, registered, result, at_thermal, scale.metres_per_unit,
                             cal, thermal_lens, box, opts, report)
    keep = result.points_error <= opts.max_reprojection_px
    counts = np.concatenate([px[px > 0] for fr, px in frames if fr.modality == "thermal"])
    lo, hi = np.percentile(counts, [0.1, 99.9]) * THERMAL_SCALE_K
    margin = 0.03 * (hi - lo)
    say(f"writing {len(frames)} frames to {out}")
    path = write_dataset(out, frames, THERMAL_SCALE_K, (round(lo - margin, 2), round(hi + margin, 2)),
                         result.points_xyz[keep] * scale.metres_per_unit, result.points_rgb[keep],
                         explicit_splits=True)
    report.output = {"frames": len(frames), "points": int(keep.sum()), "dataset": str(path)}
    report.timings["total_s"] = round(time.perf_counter() - t_start, 2)
    return path


def _dataset_frames(session, timeline: Timeline, selected, names, registered, result: SfmResult, at_thermal,
                    metres_per_unit: float, cal: RigCalibration, thermal_lens: Lens, box, opts, report):
    """(Frame, pixels) of every registered time step: the RGB frame and its paired thermal frame."""
    span = max(timeline.t1 - timeline.t0, 1e-9)
    rgb_from_thermal = cal.rgb_from_thermal
    f = opts.downscale
    out = []
    for step, n in enumerate(registered):
        s = selected[names.index(n)]
        split = "test" if opts.test_every and step % opts.test_every == opts.test_every - 1 else "train"
        cam: Lens = result.cameras[n]
        c2w = result.c2w[n].copy()
        c2w[:3, 3] *= metres_per_unit
        rgb = _downscale_rgb(s.image, f)
        k, dist = _intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.coefficients(), f)
        t_rgb = s.pair.rgb_s - timeline.t0
        out.append((Frame(f"rgb/{step:06d}_cam0.png", "rgb", "cam0", float(np.clip(t_rgb / span, 0, 1)), t_rgb,
                          c2w_opencv_to_opengl(c2w), *k, rgb.shape[1], rgb.shape[0], split, dist), rgb))
        th = session.thermal_frame(s.pair.thermal_index)
        counts = _thermal_counts(th)
        if box is not None:
            counts[_box_pixels(box, counts.shape[1], counts.shape[0])] = 0
        counts = _downscale_counts(counts, f)
        c2w_th = at_thermal[n].copy()
        c2w_th[:3, 3] *= metres_per_unit
        c2w_th = c2w_th @ rgb_from_thermal
        tl = thermal_lens
        k, dist = _intrinsics(tl.fx, tl.fy, tl.cx, tl.cy, tl.width, tl.height, tl.coefficients(), f)
        t_th = s.pair.thermal_s - timeline.t0
        out.append((Frame(f"thermal/{step:06d}_cam0.png", "thermal", "cam0", float(np.clip(t_th / span, 0, 1)),
                          t_th, c2w_opencv_to_opengl(c2w_th), *k, counts.shape[1], counts.shape[0], split, dist),
                    counts))
        report.frame_list.append({"step": step, "split": split, "rgb_record": s.pair.rgb_index,
                                  "thermal_record": s.pair.thermal_index, "rgb_host_s": s.pair.rgb_s,
                                  "thermal_host_s": s.pair.thermal_s, "sharpness": round(s.sharpness, 2)})
    return out


def _spans(times: list[float], gap: float = 0.5) -> str:
    """'1.2-2.0, 5.1' style summary of times (s)."""
    if not times:
        return "-"
    times = sorted(times)
    spans, start, prev = [], times[0], times[0]
    for t in times[1:]:
        if t - prev > gap:
            spans.append((start, prev))
            start = t
        prev = t
    spans.append((start, prev))
    return ", ".join(f"{a:.1f}" if b - a < 0.05 else f"{a:.1f}-{b:.1f}" for a, b in spans)


def _with_light_hint(message: str, low_light: bool, brightness: float) -> str:
    if not low_light:
        return message
    return (f"{message}. The phone frames are dark (median grey level {brightness:.2f}): low light gives "
            f"noisy, featureless frames; recapture with more light")
