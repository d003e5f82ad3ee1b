"""An RGBT-Scenes folder (the layout of ThermalGaussian and MMOne) -> a prepared dataset.

    SCENE/
      rgb/NAME.jpg|png ...           (or rgb/train/ + rgb/test/: the split is taken from them)
      thermal/NAME.png|tif ...       the thermal frame of the same stem (same sub-folder)
      sparse/0/cameras.bin|txt, images.bin|txt, points3D.bin|txt   (or sparse/ itself)

`recon prepare SCENE OUT` detects the layout (rgb/, thermal/ and sparse/, no session.json) and
writes the dataset without SfM: the model's poses and intrinsics are used as they are.

Thermal poses: where the model registers thermal images themselves (names that resolve into
thermal/), their own poses and cameras. Where it registers only RGB: `--thermal-aligned` (the
thermal frames were registered to the RGB view, as in the published RGBT-Scenes: same pose, the
RGB intrinsics scaled to the thermal size), or `--calibration rig_calibration.json` with `--scale`
metres per model unit (RGB pose composed with the calibrated extrinsic); otherwise it refuses.

Thermal pixels: 16-bit single-channel counts (radiometric; `--thermal-scale`, else whichever of
10 mK / 100 mK puts the median between 150 and 500 K). 8-bit or colour-mapped thermal images
(what the published datasets hold) carry no temperatures: refused unless `--non-radiometric`,
which stores grey level + 1 as counts at 1 "kelvin" per count and marks the dataset
`thermal_radiometric: false` (kelvin figures are then grey levels, a warning says so).

Times: all frames at time 0 (a static scene) unless `--times CSV` (file,timestamp rows, as `rig
import` reads them) gives each image's time.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from recon.data import Frame, c2w_opencv_to_opengl, write_dataset
from recon.prepare.frames import PrepareError
from recon.prepare.report import Report
from recon.prepare.writing import dataset_intrinsics, downscale_counts, downscale_rgb

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
SPLIT_DIRS = ("train", "test")
MODEL_FILES = ("cameras", "images", "points3D")


def model_dir(root: Path) -> Path | None:
    """sparse/0 or sparse holding cameras/images/points3D (.bin or .txt), else None."""
    for d in (root / "sparse" / "0", root / "sparse"):
        if all((d / f"{n}.bin").is_file() or (d / f"{n}.txt").is_file() for n in MODEL_FILES):
            return d
    return None


def is_rgbt_folder(path: str | Path) -> bool:
    p = Path(path)
    return (p / "rgb").is_dir() and (p / "thermal").is_dir() and (p / "sparse").is_dir() \
        and not (p / "session.json").exists()


def _model_file(d: Path, name: str) -> Path:
    return d / f"{name}.bin" if (d / f"{name}.bin").is_file() else d / f"{name}.txt"


def _check_text_model(d: Path) -> None:
    """Line-level check of a COLMAP text model, so a malformed line is named (file, line) rather
    than left to pycolmap's message. Binary models are left to pycolmap."""
    def numbers(tokens, what, path, n):
        try:
            [float(t) for t in tokens]
        except ValueError:
            raise ValueError(f"{path}: line {n}: {what} must be numbers, got {' '.join(tokens)!r}") from None

    for name, check in (("cameras", 5), ("images", 10), ("points3D", 8)):
        path = d / f"{name}.txt"
        if not path.is_file() or (d / f"{name}.bin").is_file():
            continue
        lines = [(n, ln.split()) for n, ln in enumerate(path.read_text(errors="replace").splitlines(), 1)
                 if not ln.lstrip().startswith("#")]
        if name == "images":          # pairs of lines: the pose line, then the (possibly empty) 2D points
            k = 0
            while k < len(lines):
                n, t = lines[k]
                if not t:
                    k += 1
                    continue
                if len(t) < 10:
                    raise ValueError(f"{path}: line {n}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, "
                                     f"got {' '.join(t)!r}")
                numbers(t[:9], "id, pose and camera id", path, n)
                if k + 1 < len(lines) and lines[k + 1][1]:
                    n2, t2 = lines[k + 1]
                    if len(t2) % 3:
                        raise ValueError(f"{path}: line {n2}: 2D points must be X Y POINT3D_ID triples")
                    numbers(t2, "2D points", path, n2)
                k += 2
            continue
        for n, t in lines:
            if not t:
                continue
            if len(t) < check:
                raise ValueError(f"{path}: line {n}: too few values ({' '.join(t)!r})")
            numbers(t[:1] + t[2:] if name == "cameras" else t, "values", path, n)


def read_model(d: Path):
    import pycolmap
    _check_text_model(d)
    from recon.sfm import quiet_glog
    try:
        with quiet_glog():
            return pycolmap.Reconstruction(str(d))
    except (ValueError, RuntimeError) as exc:
        text = " ".join(str(exc).split())
        where = next((_model_file(d, n) for n in MODEL_FILES if n.lower() in text.lower()), d)
        raise ValueError(f"{where}: not a readable COLMAP model ({text})") from None


def _find(base: Path, rel: str) -> Path | None:
    """rel under base, also in base/train and base/test; any image suffix for the same stem."""
    for folder in (base, *(base / s for s in SPLIT_DIRS)):
        p = folder / rel
        if p.is_file():
            return p
        for suffix in IMAGE_SUFFIXES:
            q = p.with_suffix(suffix)
            if q.is_file():
                return q
    return None


def resolve(root: Path, name: str) -> tuple[str, Path] | None:
    """A model image name -> ("rgb" | "thermal", file). Names starting with rgb/ or thermal/ (COLMAP
    run on the scene folder holding both) resolve there; other names are RGB images in rgb/."""
    parts = Path(name).parts
    modality, rel = ((parts[0], str(Path(*parts[1:]))) if len(parts) > 1 and parts[0] in ("rgb", "thermal")
                     else ("rgb", name))
    p = _find(root / modality, rel)
    return (modality, p) if p else None


def split_of(path: Path, root: Path) -> str | None:
    rel = path.relative_to(root).parts
    return rel[1] if len(rel) > 2 and rel[1] in SPLIT_DIRS else None


def thermal_partner(root: Path, rgb_path: Path) -> Path | None:
    rel = rgb_path.relative_to(root / "rgb")
    p = root / "thermal" / rel
    for q in (p, *(p.with_suffix(s) for s in IMAGE_SUFFIXES)):
        if q.is_file():
            return q
    return None


@dataclass
class View:
    modality: str
    path: Path
    c2w: np.ndarray             # (4, 4) OpenCV axes, model units
    lens: object                # rig.calibrate.Lens of the image as stored
    split: str | None


def read_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_thermal(path: Path, non_radiometric: bool) -> tuple[np.ndarray, bool]:
    """-> (uint16 counts, radiometric?). 16-bit single channel = counts; 8-bit (grey or colour-
    mapped) only with non_radiometric: grey level + 1 (0 stays 'no measurement')."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.dtype == np.uint16 and (img.ndim == 2 or all(np.array_equal(img[..., 0], img[..., c])
                                                        for c in range(1, img.shape[2]))):
        return (img if img.ndim == 2 else img[..., 0]), True
    if img.dtype != np.uint8:
        raise ValueError(f"{path}: {img.dtype} thermal pixels: expected 16-bit counts (or 8-bit with "
                         f"--non-radiometric)")
    if not non_radiometric:
        kind = "colour-mapped" if img.ndim == 3 else "8-bit grey"
        raise ValueError(f"{path}: {kind} thermal image, not radiometric (no temperatures in it); pass "
                         f"--non-radiometric to train on its grey levels (kelvin figures then meaningless), "
                         f"or give 16-bit radiometric counts")
    grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return grey.astype(np.uint16) + 1, False


def read_times(csv_path: Path) -> dict[str, float]:
    from rig.importing import read_timestamp_csv
    return read_timestamp_csv(csv_path)


def prepare_rgbt(root: str | Path, out: Path, opts, report: Report, say) -> Path:
    """Write the dataset of an RGBT-Scenes folder to `out`. opts: PrepareOptions."""
    from recon.sfm import camera_from_colmap
    root = Path(root)
    d = model_dir(root)
    if d is None:
        raise ValueError(f"{root / 'sparse'}: no COLMAP model (cameras, images, points3D as .bin or .txt) "
                         f"in sparse/0 or sparse")
    model = read_model(d)
    images_file = _model_file(d, "images")
    views: list[View] = []
    for image_id, img in sorted(model.images.items(), key=lambda kv: kv[1].name):
        found = resolve(root, img.name)
        if found is None:
            where = "thermal/" if img.name.startswith("thermal/") else "rgb/"
            raise ValueError(f"{images_file}: image {img.name!r} (id {image_id}) is not in {root / where}")
        if not img.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3, :4] = img.cam_from_world().matrix()
        try:
            lens = camera_from_colmap(model.cameras[img.camera_id])
        except RuntimeError as exc:
            raise ValueError(f"{_model_file(d, 'cameras')}: camera {img.camera_id}: {exc}") from None
        views.append(View(found[0], found[1], np.linalg.inv(w2c), lens, split_of(found[1], root)))
    rgb_views = [v for v in views if v.modality == "rgb"]
    th_views = [v for v in views if v.modality == "thermal"]
    if not rgb_views:
        raise PrepareError(f"{images_file}: the model registers no image of {root / 'rgb'}")
    report.frames.update(registered=len(views))
    used = {v.path for v in views}
    left = [p for p in (root / "rgb").rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p not in used]
    if left:
        report.warn(f"{len(left)} images of {root / 'rgb'} are not registered in the model (e.g. {left[0].name}); "
                    f"left out")
    say(f"{d}: {len(rgb_views)} RGB and {len(th_views)} thermal images registered, "
        f"{model.num_points3D()} points")

    metres, cal = 1.0, None
    if th_views:
        report.note("thermal poses: registered in the sparse model")
    elif opts.thermal_aligned:
        report.note("thermal poses: the RGB image's (--thermal-aligned: thermal frames registered to the RGB view)")
    elif opts.calibration is not None:
        from rig.calibrate import load_calibration
        cal = load_calibration(opts.calibration)
        if opts.scale is None:
            raise PrepareError(f"{d}: the model registers only the RGB images, and composing them with the "
                               f"{cal.baseline_m * 100:.1f} cm extrinsic of {opts.calibration} needs the model's "
                               f"metric scale: pass --scale METRES_PER_UNIT")
        metres = opts.scale
        report.calibration = {"source": str(opts.calibration), "method": cal.method,
                              "baseline_m": round(cal.baseline_m, 5), "rms_px": cal.rms_px}
        report.scale = {"method": "explicit", "metres_per_unit": metres}
        report.note(f"thermal poses: RGB pose composed with the extrinsic of {opts.calibration}")
    else:
        raise PrepareError(f"{d}: the model registers only the RGB images, so the thermal poses are unknown: pass "
                           f"--thermal-aligned if the thermal frames were registered to the RGB view (as in the "
                           f"published RGBT-Scenes), or --calibration rig_calibration.json with --scale")

    times = read_times(opts.times) if opts.times is not None else None

    def time_of(*paths: Path) -> float | None:
        if times is None:
            return None
        for p in paths:
            if p.name in times:
                return times[p.name]
        raise ValueError(f"{opts.times}: no timestamp for {paths[0].name}")

    # [modality, path, c2w metres OpenCV, lens, split, seconds, lens from the RGB view?]
    items = []
    for v in rgb_views:
        c2w = v.c2w.copy()
        c2w[:3, 3] *= metres
        items.append(["rgb", v.path, c2w, v.lens, v.split, time_of(v.path), False])
        if not th_views:
            tp = thermal_partner(root, v.path)
            if tp is None:
                raise ValueError(f"{v.path}: no thermal frame of the same name in {root / 'thermal'}")
            t = time_of(tp, v.path)
            if opts.thermal_aligned:
                items.append(["thermal", tp, c2w, v.lens, v.split, t, True])
            else:
                items.append(["thermal", tp, c2w @ cal.rgb_from_thermal, cal.thermal, v.split, t, True])
    for v in th_views:
        items.append(["thermal", v.path, v.c2w, v.lens, v.split, time_of(v.path), False])
    timed = [it[5] for it in items if it[5] is not None]
    t0, span = (min(timed), max(max(timed) - min(timed), 1e-9)) if timed else (0.0, 1.0)
    items.sort(key=lambda it: (it[5] or 0.0, it[1].name, it[0]))

    # splits: rgb/train + rgb/test folders, else every test_every-th RGB view (and its thermal)
    rgb_items = [it for it in items if it[0] == "rgb"]
    if any(it[4] for it in items):
        report.note("splits: from the train/ and test/ sub-folders")
        for it in items:
            it[4] = it[4] or "train"
    else:
        k = opts.test_every
        test_stems = {it[1].stem for i, it in enumerate(rgb_items) if k and i % k == k - 1}
        for it in items:
            it[4] = "test" if it[1].stem in test_stems else "train"

    f = opts.downscale
    frames, radiometric_kinds, counters = [], set(), {"rgb": 0, "thermal": 0}
    for n, (modality, path, c2w, lens, split, t, borrowed) in enumerate(items):
        if modality == "rgb":
            px = read_rgb(path)
        else:
            px, radiometric = read_thermal(path, opts.non_radiometric)
            radiometric_kinds.add(radiometric)
            if len(radiometric_kinds) > 1:
                raise ValueError(f"{path}: mixes radiometric 16-bit and 8-bit thermal frames")
        h, w = px.shape[:2]
        if abs(lens.width / lens.height - w / h) > 0.01:
            whose = (f"the calibration's thermal lens ({opts.calibration})" if borrowed and not opts.thermal_aligned
                     else f"its camera in {_model_file(d, 'cameras')}")
            raise ValueError(f"{path}: {w}x{h} pixels, but {whose} is {lens.width}x{lens.height}"
                             + (" (--thermal-aligned needs the RGB image's aspect ratio)" if borrowed else ""))
        lens = lens.scaled(w, h)
        k, dist = dataset_intrinsics(lens, f)
        px = downscale_rgb(px, f) if modality == "rgb" else downscale_counts(px, f)
        i = counters[modality]
        counters[modality] += 1
        frames.append((Frame(f"{modality}/{i:06d}_cam0.png", modality, "cam0",
                             0.0 if t is None else float((t - t0) / span), None if t is None else float(t - t0),
                             c2w_opencv_to_opengl(c2w), *k, px.shape[1], px.shape[0], split, dist), px))
        if (n + 1) % 100 == 0:
            say(f"read {n + 1}/{len(items)} images")
    if not counters["thermal"]:
        raise PrepareError(f"{root}: no thermal frame to write")

    radiometric = radiometric_kinds == {True}
    if radiometric:
        from rig.importing import choose_scale
        first = next(px for fr, px in frames if fr.modality == "thermal")
        scale_k, scale_from = choose_scale(first, opts.thermal_scale, None, next(
            it[1] for it in items if it[0] == "thermal"))
        report.note(f"thermal scale {scale_k:g} K per count ({scale_from})")
    else:
        scale_k = 1.0
        report.warn("thermal frames are 8-bit pictures, not radiometric: stored as grey level + 1 at 1 'kelvin' "
                    "per count (thermal_radiometric false); kelvin errors are grey levels and a colour map's "
                    "luminance need not follow temperature")
    valid = np.concatenate([px[px > 0] for fr, px in frames if fr.modality == "thermal"]) * scale_k
    lo, hi = np.percentile(valid, [0.1, 99.9])
    margin = 0.03 * (hi - lo) if hi > lo else 1.0
    pts = [(p.xyz, p.color) for p in model.points3D.values()]
    xyz = np.array([p[0] for p in pts], np.float64).reshape(-1, 3) * metres
    rgb = np.array([p[1] for p in pts], np.uint8).reshape(-1, 3)
    say(f"writing {len(frames)} frames to {out}")
    path = write_dataset(out, frames, scale_k, (round(float(max(lo - margin, 0.0)), 2), round(float(hi + margin), 2)),
                         xyz if len(xyz) else None, rgb if len(xyz) else None, explicit_splits=True)
    doc = json.loads(path.read_text())
    doc["source"] = {"layout": "RGBT-Scenes", "folder": str(root.resolve()), "model": str(d.resolve())}
    if not radiometric:
        doc["thermal_radiometric"] = False
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, path)
    if times is None:
        report.note("times: none given (--times), every frame at time 0 (a static scene)")
    report.frames.update(paired=counters["thermal"], selected=len(rgb_items))
    report.output = {"frames": len(frames), "points": int(len(xyz)), "dataset": str(path)}
    return path
