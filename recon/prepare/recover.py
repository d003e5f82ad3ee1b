"""Pose recovery of the selected phone frames with pycolmap, and the checks that decide whether the
recovered path can be trusted: registered fraction, mean reprojection error, path jitter.

Each check that fails raises PrepareError with the numbers and what to recapture; a partial
registration above `min_registered` keeps the registered frames (the "fewer frames" fallback)
with a warning naming the times that were dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from recon.prepare.frames import PrepareError, Selected
from recon.prepare.poses import path_jitter_deg
from recon.prepare.report import Report
from recon.prepare.writing import box_pixels
from recon.sfm import SfmError, SfmOptions, SfmResult, diagnose, run_sfm
from rig.calibrate import Lens

LOW_LIGHT = 0.3                 # median grey level below which phone frames count as dark
JITTER_WARN_DEG = 0.3           # median path jitter above which poses are called noisy
JITTER_REFERENCE_SPACING_S = 0.2  # the jitter limits hold at this frame spacing (see _check_jitter)


@dataclass
class Recovered:
    result: SfmResult
    names: list[str]            # SfM image name of each selected frame (same order)
    registered: list[int]       # indices into the selection, in time order

    def c2w(self, k: int) -> np.ndarray:
        return self.result.c2w[self.names[k]]


def sfm_inputs(selected: list[Selected], work: Path, box) -> tuple[list[str], Path | None]:
    """Write the selected frames as PNG (and masks hiding `box`) for pycolmap."""
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
    mask[box_pixels(box, w, h)] = 0
    for name in names:
        cv2.imwrite(str(masks / f"{name}.png"), mask)
    return names, masks


def colmap_camera(lens: Lens, w: int, h: int) -> tuple[str, str]:
    """Initial COLMAP camera (model, params) from the calibrated phone lens at the video's size."""
    lens = lens.scaled(w, h)
    if lens.has_distortion:
        return "OPENCV", ",".join(f"{v:.8g}" for v in (lens.fx, lens.fy, lens.cx, lens.cy, lens.k1, lens.k2,
                                                           lens.p1, lens.p2))
    return "SIMPLE_RADIAL", f"{(lens.fx + lens.fy) / 2:.8g},{lens.cx:.8g},{lens.cy:.8g},0"


def spans(times: list[float], gap: float = 0.5) -> str:
    """'1.2-2.0, 5.1' style summary of times (s)."""
    if not times:
        return "-"
    times = sorted(times)
    out, start, prev = [], times[0], times[0]
    for t in times[1:]:
        if t - prev > gap:
            out.append((start, prev))
            start = t
        prev = t
    out.append((start, prev))
    return ", ".join(f"{a:.1f}" if b - a < 0.05 else f"{a:.1f}-{b:.1f}" for a, b in out)


def light_hint(message: str, brightness: float) -> str:
    if brightness >= LOW_LIGHT:
        return message
    return (f"{message}. The phone frames are dark (median grey level {brightness:.2f}): low light gives "
            f"noisy, featureless frames; recapture with more light")


def recover_poses(selected: list[Selected], rgb_lens: Lens, box, work: Path, options, report: Report,
                  t0: float, say) -> Recovered:
    """SfM on the selected frames, then the checks. `options`: PrepareOptions."""
    brightness = report.frames["median_brightness"]
    names, mask_dir = sfm_inputs(selected, work, box)
    h, w = selected[0].image.shape[:2]
    model, params = colmap_camera(rgb_lens, w, h)
    sfm_options = SfmOptions(matching=options.matching, camera_model=model, camera_params=params,
                             mask_dir=mask_dir, refine_intrinsics=options.refine_intrinsics,
                             max_image_size=options.max_image_size, num_threads=options.threads,
                             seed=options.seed)
    say(f"pycolmap on {len(names)} frames ({options.matching} matching, {options.threads} threads)")
    try:
        result = run_sfm(work / "images", names, work / "sfm", sfm_options, say)
    except SfmError as exc:
        report.sfm = exc.stats
        raise PrepareError(light_hint(str(exc), brightness)) from None
    report.sfm = result.stats
    registered = [k for k, n in enumerate(names) if n in result.c2w]
    report.frames["registered"] = len(registered)
    missing = spans([selected[k].pair.rgb_s - t0 for k, n in enumerate(names) if n not in result.c2w])
    fraction = len(registered) / len(names)
    if fraction < options.min_registered:
        raise PrepareError(light_hint(
            f"pose recovery registered {len(registered)}/{len(names)} frames ({fraction:.0%} < "
            f"{options.min_registered:.0%}); unregistered at {missing} s. "
            + diagnose(result.stats, len(registered), len(names)), brightness))
    if len(registered) < len(names):
        report.warn(f"{len(names) - len(registered)} of {len(names)} frames did not register (at {missing} s: "
                    f"a moving object filling the view, blur or a fast turn); the dataset keeps the "
                    f"{len(registered)} registered time steps")
    err = result.stats["mean_reprojection_error_px"]
    if err > options.max_reprojection_px:
        raise PrepareError(f"mean reprojection error {err:.2f} px > {options.max_reprojection_px} px: the "
                           f"reconstruction is inconsistent (rolling shutter, motion blur, moving objects "
                           f"matched as static); recapture moving slower")
    rec = Recovered(result, names, registered)
    _check_jitter(rec, selected, options, report, brightness)
    return rec


def _check_jitter(rec: Recovered, selected, options, report: Report, brightness: float) -> None:
    times = np.array([selected[k].pair.rgb_s for k in rec.registered])
    jitter = path_jitter_deg(times, np.stack([rec.c2w(k) for k in rec.registered]))
    if not len(jitter):
        return
    med = float(np.median(jitter))
    # A smooth handheld sweep itself bends away from the slerp of its neighbours roughly with the
    # square of their spacing (the simulator's true path: 0.03 deg at 0.1 s, 0.96 at 0.5 s, 1.8 at
    # 1 s), so the limit grows with the spacing: jitter is only visible where frames are dense.
    spacing = float(np.median(np.diff(np.sort(times)))) if len(times) > 1 else 0.0
    limit = options.max_jitter_deg * max(1.0, (spacing / JITTER_REFERENCE_SPACING_S) ** 2)
    report.sfm.update(path_jitter_deg_median=round(med, 4), path_jitter_deg_max=round(float(jitter.max()), 4),
                      path_jitter_limit_deg=round(limit, 3))
    if med > limit:
        raise PrepareError(light_hint(
            f"the recovered camera path is not smooth: a pose differs by {med:.2f} deg (median) from the one "
            f"interpolated from its neighbours (> {limit:.2f} deg at {spacing:.2f} s spacing), so the poses are unreliable "
            f"(noise, blur, few features: median {rec.result.stats['features_median']:.0f} per frame). "
            f"Recapture with more light and slower motion", brightness))
    if med > JITTER_WARN_DEG * limit / options.max_jitter_deg:
        report.warn(f"noisy poses: path jitter {med:.2f} deg median (> {JITTER_WARN_DEG}); expect blurred "
                    f"thermal alignment" + (" (low light)" if brightness < LOW_LIGHT else ""))
