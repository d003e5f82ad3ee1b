"""`prepare_session`: a rig session -> a prepared dataset (shared/FORMATS.md) with poses.

Steps: find the rig calibration; sync and pair thermal with phone frames; pick one sharp phone
frame per time bin (frames.py); recover their poses and sparse points with pycolmap and check
them (recover.py); find the metric scale (scale.py); give each thermal frame the RGB pose
interpolated to its own time composed with the calibrated extrinsic; write images, poses,
intrinsics, `points3d.ply` (writing.py) and `prepare_report.json` (report.py). Whatever cannot
be trusted stops the run with a `PrepareError` that says what was measured and what to
recapture; the report is written either way.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from recon.data import write_dataset
from recon.prepare.frames import PrepareError, select_frames, session_timeline
from recon.prepare.poses import interpolate_pose
from recon.prepare.recover import LOW_LIGHT, recover_poses
from recon.prepare.report import REPORT_FILE, Report
from recon.prepare.rgbt import is_rgbt_folder, prepare_rgbt
from recon.prepare.scale import DEPTH_RANGE_M, median_depth_units, metric_scale
from recon.prepare.writing import THERMAL_SCALE_K, Step, dataset_frames, thermal_range_k
from recon.sfm import SfmError
from rig.calibrate import CalibrationError, Target, find_calibration
from rig.session import open_session



@dataclass
class PrepareOptions:
    calibration: Path | None = None      # rig_calibration.json (default: found beside the session)
    frames: int = 80                     # time steps picked over the session (one RGB + one thermal each)
    test_every: int = 8                  # every n-th time step is held out as test; 0: none
    scale: float | None = None           # metres per SfM unit (default: checkerboard in view, see scale.py)
    downscale: int = 1                   # integer factor applied to the written images
    matching: str = "sequential"         # pycolmap pairing: "sequential" (+ loop closure) or "exhaustive"
    mask_box: tuple[float, float, float, float] | None = None   # x0 y0 x1 y1 fractions, e.g. the sync lamp
    min_registered: float = 0.8          # refuse below this fraction of registered frames
    max_reprojection_px: float = 2.0     # refuse above this mean reprojection error
    max_jitter_deg: float = 1.0          # refuse above this median path jitter (poses.path_jitter_deg)
    refine_intrinsics: bool = False      # let bundle adjustment refine the calibrated phone intrinsics
    max_image_size: int = 1600
    keep_work: bool = False              # keep OUT/.work (SfM images, database, model)
    threads: int = 2
    seed: int = 0
    # RGBT-Scenes folders only (rgbt.py): thermal kelvin per count (None: 10/100 mK by the median),
    # a file,timestamp CSV (None: static, time 0), thermal frames registered to the RGB view, and
    # 8-bit colour-mapped thermal accepted as grey levels
    thermal_scale: float | None = None
    times: Path | None = None
    thermal_aligned: bool = False
    non_radiometric: bool = False

    def __post_init__(self):
        if self.frames < 3 or self.downscale < 1 or self.test_every < 0:
            raise ValueError("frames must be >= 3, downscale >= 1, test_every >= 0")
        if self.scale is not None and not self.scale > 0:
            raise ValueError(f"scale must be positive metres per SfM unit, got {self.scale}")
        if self.calibration is not None:
            self.calibration = Path(self.calibration)
        if self.thermal_scale is not None and not self.thermal_scale > 0:
            raise ValueError(f"thermal_scale must be positive kelvin per count, got {self.thermal_scale}")
        if self.times is not None:
            self.times = Path(self.times)


def lamp_box(session, options: PrepareOptions) -> tuple[float, ...] | None:
    """Image box hidden from SfM and unmeasured in thermal: --mask, else the sync lamp's box a
    simulated session records, else session.json's `lamp_box`."""
    if options.mask_box is not None:
        return tuple(options.mask_box)
    for t in (session.summary or {}).get("sim_truth") or []:
        if (t.get("scene") or {}).get("lamp_box"):
            return tuple(t["scene"]["lamp_box"])
    return session.meta.get("lamp_box")


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
        if is_rgbt_folder(session_dir):
            path = prepare_rgbt(Path(session_dir), out, opts, report, say)
        else:
            path = _prepare(Path(session_dir), out, opts, report, say)
        report.finish("ok")
        return path
    except (PrepareError, SfmError, CalibrationError) as exc:
        report.finish("failed", str(exc))
        raise PrepareError(str(exc)) from exc
    except (ValueError, OSError) as exc:           # malformed input: the message names the file
        report.finish("failed", str(exc))
        raise
    finally:
        report.write(out / REPORT_FILE)
        if not opts.keep_work:
            shutil.rmtree(out / ".work", ignore_errors=True)


def check_streams(session, session_dir: Path) -> None:
    """What no later step can make up for: phone frames (the poses come from them) and
    temperatures (a camera without radiometric features needs a stated counts-to-kelvin map)."""
    if not session.rgb:
        raise PrepareError(f"{session_dir} holds no phone video or photos ({len(session.thermal)} thermal frames "
                           f"only): poses come from the phone; record with `rig capture --phone-drop FOLDER` "
                           f"(or add the phone's files with `rig import`)")
    th = session.meta.get("thermal", {})
    if th.get("radiometric") is False and not th.get("kelvin_map"):
        raise PrepareError(f"{session_dir}: the thermal camera ({th.get('profile')} profile) recorded counts, "
                           f"not temperatures; record with `rig capture --kelvin-map GAIN,OFFSET` (kelvin per "
                           f"count and at count 0, from the camera's own calibration)")


def _prepare(session_dir: Path, out: Path, opts: PrepareOptions, report: Report, say) -> Path:
    t_start = time.perf_counter()
    try:
        session = open_session(session_dir)
    except (FileNotFoundError, ValueError) as exc:
        raise PrepareError(str(exc)) from None
    if not session.closed:
        report.warn("the session has no closed.json (still capturing, or it crashed): using the frames "
                    "committed so far")
    check_streams(session, session_dir)
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
    report.frames.update(paired=len(timeline.pairs), selected=len(selected), median_brightness=round(brightness, 4),
                         median_sharpness=round(float(np.median([s.sharpness for s in selected])), 2))
    if brightness < LOW_LIGHT:
        report.warn(f"low light: median grey level {brightness:.2f} (< {LOW_LIGHT}) in the phone frames; "
                    f"more light gives more features and steadier poses")

    box = lamp_box(session, opts)
    shutil.rmtree(out / ".work", ignore_errors=True)
    rec = recover_poses(selected, cal.rgb, box, out / ".work", opts, report, timeline.t0, say)

    th0 = session.thermal_frame(selected[0].pair.thermal_index)
    h_th, w_th = th0.counts.shape
    if abs(cal.thermal.width / cal.thermal.height - w_th / h_th) > 0.01:
        raise PrepareError(f"the calibration's thermal image is {cal.thermal.width}x{cal.thermal.height} but "
                           f"the session's is {w_th}x{h_th}: calibrate this camera mode")
    target = Target(tuple((cal.target or {}).get("pattern", (8, 6))), (cal.target or {}).get("square_m", 0.016))
    scale = metric_scale(opts.scale, session, rec, selected, target)
    report.scale = {"method": scale.method, "metres_per_unit": scale.metres_per_unit, **scale.detail}
    if scale.method == "simulator":
        report.note(f"metric scale: the simulator's true camera path (documented fallback for simulated "
                    f"sessions; {scale.detail['reason']})")
    if scale.metres_per_unit is None:
        raise PrepareError(
            f"metric scale unknown ({scale.detail.get('reason', 'no estimate')}): the thermal poses need the "
            f"{cal.baseline_m * 100:.1f} cm RGB-thermal baseline in SfM units. Recapture with the "
            f"calibration checkerboard (flat, whole, in view of the phone) for a few seconds, or pass "
            f"--scale METRES_PER_UNIT")
    depth_m = median_depth_units(rec.result) * scale.metres_per_unit
    report.scale["median_depth_m"] = round(depth_m, 4)
    if not DEPTH_RANGE_M[0] <= depth_m <= DEPTH_RANGE_M[1]:
        raise PrepareError(f"metric scale implausible: the scene would be {depth_m:.3f} m from the camera "
                           f"(expected {DEPTH_RANGE_M[0]}-{DEPTH_RANGE_M[1]} m); check --scale or the target size")

    steps = _steps(rec, selected, scale.metres_per_unit, cal.rgb_from_thermal, opts.test_every)
    frames = dataset_frames(session, timeline, steps, cal.thermal.scaled(w_th, h_th), opts.downscale, box)
    keep = rec.result.points_error <= opts.max_reprojection_px
    say(f"writing {len(frames)} frames to {out}")
    path = write_dataset(out, frames, THERMAL_SCALE_K, thermal_range_k(frames),
                         rec.result.points_xyz[keep] * scale.metres_per_unit, rec.result.points_rgb[keep],
                         explicit_splits=True)
    report.frame_list = [{"step": i, "split": st.split, "rgb_record": st.selected.pair.rgb_index,
                          "thermal_record": st.selected.pair.thermal_index, "rgb_host_s": st.selected.pair.rgb_s,
                          "thermal_host_s": st.selected.pair.thermal_s,
                          "sharpness": round(st.selected.sharpness, 2)} for i, st in enumerate(steps)]
    report.output = {"frames": len(frames), "points": int(keep.sum()), "dataset": str(path)}
    report.timings["total_s"] = round(time.perf_counter() - t_start, 2)
    return path


def _steps(rec, selected, metres_per_unit: float, rgb_from_thermal: np.ndarray, test_every: int) -> list[Step]:
    """Metric poses of each registered time step. The thermal pose is the RGB path slerped to the
    thermal frame's own time (up to half a frame from its phone frame) composed with the extrinsic."""
    times = np.array([selected[k].pair.rgb_s for k in rec.registered])
    path = np.stack([rec.c2w(k) for k in rec.registered])
    path[:, :3, 3] *= metres_per_unit
    steps = []
    for i, k in enumerate(rec.registered):
        s = selected[k]
        split = "test" if test_every and i % test_every == test_every - 1 else "train"
        c2w_th = interpolate_pose(times, path, s.pair.thermal_s) @ rgb_from_thermal
        steps.append(Step(s, path[i], rec.result.cameras[rec.names[k]], c2w_th, split))
    return steps
