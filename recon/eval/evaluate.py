"""Compare a run's renders with a prepared dataset's ground truth (`recon eval`).

Per frame and modality: PSNR and SSIM (3DGS convention, see metrics.py) on [0, 1] images —
thermal as temperature normalised with thermal_range_k and clipped to [0, 1], over pixels with
a measurement — LPIPS (AlexNet, official [-1, 1] convention; thermal as the normalised
temperature repeated in three channels) when weights are installed, and for thermal the mean
absolute error in kelvin over valid pixels. A render's thermal count 0 decodes to 0 K (a
render must predict every pixel). Means are plain means over frames, as the 3DGS scripts do.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from recon.data import Dataset, Frame, load_dataset
from recon.eval.lpips import CONVENTION as LPIPS_CONVENTION
from recon.eval.lpips import MIN_SIDE as LPIPS_MIN_SIDE
from recon.eval.lpips import Lpips
from recon.eval.metrics import psnr, ssim, thermal_mae_k
from recon.viz import rgb_strip, save_png, thermal_strip
from recon.eval.regions import (RegionPool, changing_pixels, frame_regions, moving_from_labels, object_masks,
                                object_names)
from recon.eval.renders import RenderError, find_render, read_render, render_path

METRICS = {"rgb": ("psnr", "ssim", "lpips"), "thermal": ("psnr", "ssim", "lpips", "mae_k")}
MAX_MEDIAN_FRAMES = 64      # frames in a still camera's temporal median (memory)
REGIONS_CONVENTION = ("moving: object masks (mask_labels marks which labels move) or, for a still camera, "
                      "pixels that change over the sequence; hot: >= the frame's median temperature + 10 K; "
                      "moving_hot: both; static: not moving. Pixels pooled over frames: thermal MAE and 95th "
                      "percentile in kelvin, RGB PSNR of the pooled squared error.")


def _normalise(kelvin: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    return np.clip((kelvin - span[0]) / (span[1] - span[0]), 0, 1)


def moving_masks(ds: Dataset, frames: list[Frame]) -> dict[str, np.ndarray | None]:
    """Moving-object pixels (H, W) bool of each frame, by file_path: from its mask, or for a
    camera that never moves from where its ground truth changes, else None (regions.py)."""
    out: dict[str, np.ndarray | None] = {}
    for f in frames:
        out[f.file_path] = None if f.mask_path is None else moving_from_labels(ds.mask(f), ds.mask_labels)
    unmasked = [f for f in frames if f.mask_path is None]
    for key in sorted({(f.camera, f.modality) for f in unmasked}):
        group = [f for f in ds.frames if (f.camera, f.modality) == key]
        if len(group) < 3 or not all(np.allclose(f.c2w, group[0].c2w, atol=1e-6) for f in group):
            continue                      # a moving camera: what changes is not known without masks
        picks = group[:: max(1, len(group) // MAX_MEDIAN_FRAMES)]
        reference = [ds.image(f) for f in picks]
        for f in (f for f in unmasked if (f.camera, f.modality) == key):
            out[f.file_path] = changing_pixels(reference + [ds.image(f)], f.modality)[-1]
    return out


def frame_metrics(ds: Dataset, frame: Frame, render: np.ndarray, lpips: Lpips | None,
                  pool: RegionPool | None = None, moving: np.ndarray | None = None) -> dict:
    """Metrics of one frame given the render's stored pixels (uint8 RGB or uint16 counts); with
    a pool, also its region metrics (added to the pool, and to the result under "regions")."""
    gt = ds.image(frame)
    if frame.modality == "rgb":
        a, b, valid = render.astype(np.float32) / 255, gt, None
    else:
        valid = np.isfinite(gt)
        pred_k = render.astype(np.float32) * np.float32(ds.thermal_scale_k)
        a = np.where(valid, _normalise(pred_k, ds.thermal_range_k), 0).astype(np.float32)
        b = np.where(valid, _normalise(gt, ds.thermal_range_k), 0).astype(np.float32)
    a_t, b_t = torch.from_numpy(a), torch.from_numpy(np.array(b))  # b may be a read-only cache entry
    out = {"psnr": float(psnr(a_t, b_t, valid)), "ssim": float(ssim(a_t, b_t, valid))}
    if lpips is not None:
        rgb_a, rgb_b = (a_t, b_t) if a_t.ndim == 3 else (a_t[..., None].expand(-1, -1, 3),
                                                         b_t[..., None].expand(-1, -1, 3))
        out["lpips"] = float(lpips(rgb_a, rgb_b))
    if frame.modality == "thermal":
        out["mae_k"] = float(thermal_mae_k(pred_k, gt, valid))
    if pool is not None:
        error = np.abs(pred_k - gt) if frame.modality == "thermal" else (a - np.asarray(b)) ** 2
        regions = frame_regions(frame.modality, np.asarray(gt), valid, moving)
        out["regions"] = pool.add(frame.modality, regions, np.nan_to_num(error))
        names = object_names(ds.mask_labels)
        moves = {names[k]: bool(v.get("moving", True)) for k, v in ds.mask_labels.items()}
        pool.add_objects(frame.modality, object_masks(ds.mask(frame), names, valid),
                         np.nan_to_num(error), moves)
    return out


def evaluate_run(run_dir: str | Path, dataset_dir: str | Path, split: str = "test",
                 use_lpips: bool = True, progress=None, modalities=("rgb", "thermal")) -> dict:
    """Metrics of every frame of `split` ('test', 'train' or 'all') and of the given modalities
    (a single-modality method renders only its own), per frame and mean per modality.

    Raises RenderError (a ValueError) naming the missing or mismatched render(s) before
    computing anything, and DatasetError for a malformed dataset.
    """
    ds = load_dataset(dataset_dir)
    frames = [f for f in ds.frames if (split == "all" or f.split == split) and f.modality in modalities]
    if not frames:
        raise ValueError(f"{dataset_dir}: no {split} frames to evaluate")
    missing = [str(render_path(run_dir, f)) for f in frames if find_render(run_dir, f) is None]
    if missing:
        raise RenderError(f"{len(missing)} of {len(frames)} renders missing, e.g. {missing[0]}"
                          + (f" and {missing[1]}" if len(missing) > 1 else ""))
    lpips, lpips_note = None, "omitted: LPIPS weights not installed (run `make setup`)"
    if not use_lpips:
        lpips_note = "omitted: disabled (--no-lpips)"
    elif min(min(f.width, f.height) for f in frames) < LPIPS_MIN_SIDE:
        lpips_note = f"omitted: frames smaller than {LPIPS_MIN_SIDE} px (AlexNet's receptive field)"
    elif Lpips.available():
        lpips, lpips_note = Lpips(), LPIPS_CONVENTION
    per_frame, pool, moving = [], RegionPool(), moving_masks(ds, frames)
    with torch.no_grad():
        for i, frame in enumerate(frames):
            values = frame_metrics(ds, frame, read_render(run_dir, frame), lpips, pool, moving[frame.file_path])
            per_frame.append({"file_path": frame.file_path, "modality": frame.modality,
                              "camera": frame.camera, "time": frame.time, **values})
            if progress:
                progress(i + 1, len(frames))
    means = {}
    for modality, names in METRICS.items():
        rows = [r for r in per_frame if r["modality"] == modality]
        if rows:
            means[modality] = {"frames": len(rows),
                               **{n: float(np.mean([r[n] for r in rows])) for n in names if n in rows[0]}}
    return {
        "run": str(run_dir), "dataset": str(dataset_dir), "split": split,
        "conventions": {
            "ssim": "3DGS: 11x11 Gaussian window, sigma 1.5, zero padding, mean over the map",
            "thermal": f"PSNR/SSIM/LPIPS on temperature normalised with thermal_range_k "
                       f"{list(ds.thermal_range_k or [])} and clipped to [0, 1]; MAE in kelvin "
                       f"over pixels with a measurement",
            "lpips": lpips_note,
            "regions": REGIONS_CONVENTION + ("" if all(v is not None for v in moving.values()) else
                                             " Some frames have no masks and a moving camera: their "
                                             "moving and static regions are unknown (null)."),
        },
        "mean": means,
        "regions": pool.result(),
        "objects": pool.objects(),
        "per_frame": per_frame,
    }


def write_strips(run_dir: str | Path, dataset_dir: str | Path, out_dir: str | Path,
                 split: str = "test", modalities=("rgb", "thermal")) -> list[Path]:
    """GT | render | error pictures (recon.viz) of every evaluated frame, at out_dir/<file_path>.png."""
    ds = load_dataset(dataset_dir)
    written = []
    for frame in (f for f in ds.frames if (split == "all" or f.split == split) and f.modality in modalities):
        render = read_render(run_dir, frame)
        if frame.modality == "rgb":
            picture = rgb_strip(ds.image(frame), render)
        else:
            picture = thermal_strip(ds.image(frame), render * ds.thermal_scale_k, *ds.thermal_range_k)
        written.append(save_png(Path(out_dir) / Path(frame.file_path).with_suffix(".png"), picture))
    return written


def _fmt(value: float | None, digits: int) -> str:
    if value is None:
        return "–"
    return "inf" if math.isinf(value) else f"{value:.{digits}f}"


def region_table(regions: dict) -> list[str]:
    """Markdown lines: one row per modality and region (unknown regions say so)."""
    if not regions:
        return []
    lines = ["", "| modality | region | pixels | MAE (K) | p95 (K) | PSNR (dB) |", "|---|---|---|---|---|---|"]
    for modality, by_region in regions.items():
        for name, m in by_region.items():
            if m is None:
                lines.append(f"| {modality} | {name} | unknown | – | – | – |")
                continue
            lines.append(f"| {modality} | {name} | {m['pixels']} | {_fmt(m.get('mae_k'), 3)} | "
                         f"{_fmt(m.get('p95_k'), 2)} | {_fmt(m.get('psnr'), 2)} |")
    return lines


def object_table(objects: dict) -> list[str]:
    """Markdown lines: one row per modality and named object (datasets with mask_labels)."""
    if not any(objects.values()):
        return []
    lines = ["", "| modality | object | moves | pixels | MAE (K) | p95 (K) | PSNR (dB) |", "|---|---|---|---|---|---|---|"]
    for modality, by_name in objects.items():
        for name, m in by_name.items():
            lines.append(f"| {modality} | {name} | {'yes' if m['moving'] else 'no'} | {m['pixels']} | "
                         f"{_fmt(m.get('mae_k'), 3)} | {_fmt(m.get('p95_k'), 2)} | {_fmt(m.get('psnr'), 2)} |")
    return lines


def markdown_table(result: dict) -> str:
    """Mean table per modality, then every frame."""
    cols = [("psnr", "PSNR (dB)", 2), ("ssim", "SSIM", 4), ("lpips", "LPIPS", 4), ("mae_k", "MAE (K)", 3)]
    lines = [f"# Evaluation of {result['run']} on {result['dataset']} ({result['split']} frames)", "",
             "| modality | frames | " + " | ".join(c[1] for c in cols) + " |",
             "|---|---|" + "---|" * len(cols)]
    for modality, m in result["mean"].items():
        lines.append(f"| {modality} | {m['frames']} | "
                     + " | ".join(_fmt(m.get(k), d) for k, _, d in cols) + " |")
    lines += region_table(result.get("regions", {}))
    lines += object_table(result.get("objects", {}))
    lines += ["", *(f"- {k}: {v}" for k, v in result["conventions"].items()), "",
              "| frame | modality | time | " + " | ".join(c[1] for c in cols) + " |",
              "|---|---|---|" + "---|" * len(cols)]
    for r in result["per_frame"]:
        lines.append(f"| {r['file_path']} | {r['modality']} | {r['time']:.3f} | "
                     + " | ".join(_fmt(r.get(k), d) for k, _, d in cols) + " |")
    return "\n".join(lines) + "\n"


def _json_safe(x):
    """inf/NaN are not JSON: written as the strings "inf", "-inf", "nan"."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    return x


def write_results(result: dict, out_dir: str | Path) -> tuple[Path, Path]:
    """metrics.json and metrics.md in out_dir."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    js, md = out / "metrics.json", out / "metrics.md"
    js.write_text(json.dumps(_json_safe(result), indent=1) + "\n")
    md.write_text(markdown_table(result))
    return js, md
