"""Errors where they matter: metrics per region of the test frames.

A whole-image thermal MAE of 1.3 K can hide a moving hot ball that is 30-40 K off: the objects a
thermographer came to measure are a few percent of the pixels. Regions of a frame:

- ``moving``: pixels of a moving object. From the dataset's object masks (``mask_path`` per
  frame, ``mask_labels`` saying which labels move; without ``mask_labels`` every nonzero label
  counts). Without masks, for a camera that stays put over the sequence: pixels whose ground
  truth changes (thermal: more than 2 K from the pixel's temporal median, RGB: more than 0.1 in
  some channel). Without masks and with a moving camera it is unknown (None).
- ``hot`` (thermal): ground truth at least 10 K above the frame's median temperature.
- ``moving_hot`` (thermal): both.
- ``static``: valid pixels not moving (unknown when moving is).

Objects: with masks and named ``mask_labels``, each labelled object is a region of its own
(``object_masks``): the error on the ball, the pan or the solder tip, whichever else is in view.
Frames without masks add nothing to them; an object out of every evaluated frame is not listed.

Metrics pool the pixels of every evaluated frame of a modality (so a frame with a sliver of a
region does not weigh as much as one where it fills the view): thermal ``mae_k``, ``p95_k`` (95th
percentile of the absolute error) and ``pixels``; RGB ``psnr`` of the pooled squared error over
the region's pixels and channels, and ``pixels``.
"""
from __future__ import annotations

import math

import numpy as np

HOT_ABOVE_MEDIAN_K = 10.0
CHANGE_K = 2.0
CHANGE_RGB = 0.1
REGIONS = {"rgb": ("moving", "static"), "thermal": ("moving", "hot", "moving_hot", "static")}


def moving_from_labels(labels: np.ndarray, mask_labels: dict[int, dict]) -> np.ndarray:
    """(H, W) bool: pixels whose object label is marked moving (every nonzero label if the
    dataset does not say which move)."""
    if not mask_labels:
        return labels > 0
    moving = [k for k, v in mask_labels.items() if v["moving"]]
    return np.isin(labels, moving)


def object_names(mask_labels: dict[int, dict]) -> dict[int, str]:
    """label -> the object's name (``label N`` when it has none; repeated names get their label)."""
    names = {k: str(v.get("name") or f"label {k}") for k, v in mask_labels.items()}
    counts: dict[str, int] = {}
    for n in names.values():
        counts[n] = counts.get(n, 0) + 1
    return {k: n if counts[n] == 1 else f"{n} (label {k})" for k, n in names.items()}


def object_masks(labels: np.ndarray | None, names: dict[int, str],
                 valid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """(H, W) bool per named object present in this frame's labels (valid pixels only); names:
    object_names() of the dataset's mask_labels. {} without a mask or without names (unnamed
    labels are not objects a user can look up)."""
    if labels is None or not names:
        return {}
    present = set(np.unique(labels).tolist())
    out = {}
    for k, name in names.items():
        if k in present:
            m = labels == k
            out[name] = m if valid is None else m & valid
    return out


def changing_pixels(images: list[np.ndarray], modality: str) -> list[np.ndarray]:
    """For frames of one still camera: (H, W) bool per frame where the image departs from the
    pixel's temporal median (thermal kelvin with NaN = no measurement, or RGB in [0, 1])."""
    stack = np.stack(images).astype(np.float64)
    median = np.nanmedian(stack, axis=0)
    off = np.abs(stack - median)
    if modality == "rgb":
        return list(off.max(axis=-1) > CHANGE_RGB)
    return list(np.nan_to_num(off, nan=0.0) > CHANGE_K)


def frame_regions(modality: str, gt: np.ndarray, valid: np.ndarray | None,
                  moving: np.ndarray | None) -> dict[str, np.ndarray | None]:
    """Region masks (H, W) bool of one frame (None: unknown). gt: RGB (H, W, 3) or kelvin (H, W)."""
    valid = np.ones(gt.shape[:2], bool) if valid is None else valid
    out: dict[str, np.ndarray | None] = {
        "moving": None if moving is None else moving & valid,
        "static": None if moving is None else valid & ~moving}
    if modality == "thermal":
        hot = valid & (gt >= np.median(gt[valid]) + HOT_ABOVE_MEDIAN_K) if valid.any() else valid
        out["hot"] = hot
        out["moving_hot"] = None if moving is None else hot & moving
    return out


def _thermal(errors: np.ndarray) -> dict:
    if errors.size == 0:
        return {"mae_k": None, "p95_k": None, "pixels": 0}
    return {"mae_k": float(errors.mean()), "p95_k": float(np.percentile(errors, 95)), "pixels": int(errors.size)}


def _rgb(squared: np.ndarray) -> dict:
    if squared.size == 0:
        return {"psnr": None, "pixels": 0}
    mse = float(squared.mean())
    return {"psnr": math.inf if mse == 0 else 10 * math.log10(1 / mse), "pixels": int(squared.shape[0])}


class RegionPool:
    """Collects each region's (and object's) pixel errors over frames; `result()` and `objects()`
    give the pooled metrics."""

    def __init__(self):
        self._errors: dict[str, dict[str, list]] = {}
        self._known: dict[str, dict[str, bool]] = {}
        self._objects: dict[str, dict[str, list]] = {}
        self._moving: dict[str, bool] = {}

    def add_objects(self, modality: str, objects: dict[str, np.ndarray], error: np.ndarray,
                    moving: dict[str, bool]) -> None:
        """objects: object_masks() of a frame; error as in add(); moving: name -> whether it moves."""
        for name, mask in objects.items():
            self._objects.setdefault(modality, {}).setdefault(name, []).append(error[mask])
            self._moving[name] = bool(moving.get(name, True))

    def objects(self) -> dict[str, dict[str, dict]]:
        """{modality: {object name: pooled metrics + "moving"}}, objects in name order."""
        out = {}
        for modality, by_name in self._objects.items():
            out[modality] = {}
            for name in sorted(by_name):
                pooled = np.concatenate(by_name[name])
                metrics = _thermal(pooled) if modality == "thermal" else _rgb(pooled)
                out[modality][name] = {**metrics, "moving": self._moving[name]}
        return out

    def add(self, modality: str, regions: dict[str, np.ndarray | None], error: np.ndarray) -> dict:
        """error: thermal |pred - gt| kelvin (H, W), or RGB squared error (H, W, 3). Returns this
        frame's own region metrics."""
        frame = {}
        for name in REGIONS[modality]:
            mask = regions.get(name)
            known = self._known.setdefault(modality, {})
            known[name] = known.get(name, True) and mask is not None
            if mask is None:
                frame[name] = None
                continue
            picked = error[mask]
            self._errors.setdefault(modality, {}).setdefault(name, []).append(picked)
            frame[name] = _thermal(picked) if modality == "thermal" else _rgb(picked)
        return frame

    def result(self) -> dict[str, dict[str, dict | None]]:
        out = {}
        for modality, known in self._known.items():
            out[modality] = {}
            for name, ok in known.items():
                parts = self._errors.get(modality, {}).get(name, [])
                if not ok or not parts:
                    out[modality][name] = None
                    continue
                pooled = np.concatenate(parts)
                out[modality][name] = _thermal(pooled) if modality == "thermal" else _rgb(pooled)
        return out
