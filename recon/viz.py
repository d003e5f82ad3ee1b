"""Thermal pictures people can read: colour maps, °C colourbars, GT / render / error strips.

Every function returns an RGB uint8 image (H, W, 3); write it with `save_png`. Temperatures
are kelvin (NaN = no measurement, drawn grey); colourbars are labelled in °C, error maps in K.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

C0 = 273.15
INVALID_RGB = (110, 110, 110)
# FLIR-style ironbow: black -> indigo -> magenta -> red -> orange -> yellow -> white
_IRONBOW_STOPS = np.array([
    (0.00, (0, 0, 0)), (0.12, (32, 0, 96)), (0.28, (110, 0, 150)), (0.45, (190, 30, 110)),
    (0.60, (235, 80, 30)), (0.75, (250, 150, 0)), (0.90, (255, 225, 60)), (1.00, (255, 255, 240)),
], dtype=object)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def colormap(name: str = "ironbow") -> np.ndarray:
    """(256, 3) uint8 RGB lookup table: 'ironbow' or 'inferno'."""
    if name == "inferno":
        lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_INFERNO)
        return lut[:, 0, ::-1].copy()
    if name == "ironbow":
        pos = np.array([p for p, _ in _IRONBOW_STOPS], float)
        rgb = np.array([c for _, c in _IRONBOW_STOPS], float)
        x = np.linspace(0, 1, 256)
        return np.stack([np.interp(x, pos, rgb[:, i]) for i in range(3)], 1).round().astype(np.uint8)
    raise ValueError(f"unknown colour map {name!r}; use 'ironbow' or 'inferno'")


def colorize(values: np.ndarray, vmin: float, vmax: float, cmap: str = "ironbow") -> np.ndarray:
    """(H, W) values -> (H, W, 3) uint8 through the colour map; NaN -> grey."""
    values = np.asarray(values, np.float64)
    t = np.clip((values - vmin) / max(vmax - vmin, 1e-12), 0, 1)
    idx = np.nan_to_num(t * 255, nan=0).round().astype(np.intp)
    out = colormap(cmap)[idx]
    out[~np.isfinite(values)] = INVALID_RGB
    return out


def _nice_ticks(lo: float, hi: float, count: int = 6) -> np.ndarray:
    """Round tick values (1, 2, 5 x 10^k steps) inside [lo, hi]."""
    span = max(hi - lo, 1e-9)
    magnitude = 10 ** np.floor(np.log10(span / count))
    step = next(m * magnitude for m in (1, 2, 5, 10) if span / (m * magnitude) <= count)
    first = np.ceil(lo / step) * step
    return np.arange(first, hi + step * 1e-6, step)


def _put_text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, thick: int = 1) -> None:
    """cv2.putText in black; Hershey fonts lack '°', so it is drawn as a small ring."""
    x, y = org
    for i, part in enumerate(text.split("°")):
        if i:
            r = max(2, int(round(4 * scale)))
            cv2.circle(img, (x + r, y - int(18 * scale)), r, (0, 0, 0), thick, cv2.LINE_AA)
            x += 2 * r + 2
        cv2.putText(img, part, (x, y), _FONT, scale, (0, 0, 0), thick, cv2.LINE_AA)
        x += cv2.getTextSize(part, _FONT, scale, thick)[0][0]


def _text_size(height: int) -> tuple[float, int]:
    scale = max(0.35, min(0.6, height / 500))
    return scale, 1


def colorbar_ticks(vmin: float, vmax: float, offset: float = -C0) -> tuple[np.ndarray, list[str]]:
    """Tick values and labels of a colourbar spanning vmin..vmax kelvin, in the label unit
    (value + offset: °C by default), with as many decimals as the tick step needs."""
    ticks = _nice_ticks(vmin + offset, vmax + offset)
    decimals = 0 if len(ticks) < 2 or ticks[1] - ticks[0] >= 1 else 1 if ticks[1] - ticks[0] >= 0.1 else 2
    return ticks, [f"{t:.{decimals}f}" for t in ticks]


def colorbar(height: int, vmin: float, vmax: float, cmap: str = "ironbow", unit: str = "°C",
             offset: float = -C0) -> np.ndarray:
    """A vertical bar (height, ~60-80, 3) with ticks labelled in `unit`; values are kelvin and
    labels show value + offset (°C by default; use offset 0 and unit 'K' for differences)."""
    scale, thick = _text_size(height)
    lo, hi = vmin + offset, vmax + offset
    ticks, labels = colorbar_ticks(vmin, vmax, offset)
    text_w = max([cv2.getTextSize(s, _FONT, scale, thick)[0][0] for s in labels + [unit]])
    bar_w, pad, margin = 14, 4, 10
    out = np.full((height, bar_w + 2 * pad + text_w + margin, 3), 255, np.uint8)
    top, bottom = margin + 10, height - margin
    ramp = np.linspace(1, 0, bottom - top)[:, None].repeat(bar_w, 1)
    out[top:bottom, pad:pad + bar_w] = colorize(ramp, 0, 1, cmap)
    _put_text(out, unit, (pad, top - 4), scale, thick)
    for value, label in zip(ticks, labels):
        y = int(round(bottom - (value - lo) / max(hi - lo, 1e-12) * (bottom - top)))
        cv2.line(out, (pad + bar_w, y), (pad + bar_w + 3, y), (0, 0, 0), 1)
        (_, th), _ = cv2.getTextSize(label, _FONT, scale, thick)
        _put_text(out, label, (pad + bar_w + 5, min(max(y + th // 2, th), height - 2)), scale, thick)
    return out


def _upscale(img: np.ndarray, min_height: int) -> np.ndarray:
    """Nearest-neighbour enlargement by an integer factor so labels fit small frames."""
    factor = max(1, int(np.ceil(min_height / img.shape[0])))
    return img if factor == 1 else np.repeat(np.repeat(img, factor, 0), factor, 1)


def _titled(img: np.ndarray, title: str | None) -> np.ndarray:
    if not title:
        return img
    scale, thick = _text_size(max(img.shape[0], 200))
    band = np.full((int(28 * scale / 0.5), img.shape[1], 3), 255, np.uint8)
    _put_text(band, title, (4, band.shape[0] - 7), scale, thick)
    return np.concatenate([band, img], 0)


def _range(*images: np.ndarray) -> tuple[float, float]:
    finite = np.concatenate([np.asarray(i, np.float64)[np.isfinite(i)] for i in images])
    if not finite.size:
        return C0, C0 + 1
    lo, hi = np.percentile(finite, [0.5, 99.5])
    return float(lo), float(max(hi, lo + 0.1))


def thermal_image(kelvin: np.ndarray, vmin_k: float | None = None, vmax_k: float | None = None,
                  cmap: str = "ironbow", title: str | None = None, min_height: int = 240) -> np.ndarray:
    """One thermal frame in colour with a °C colourbar (range: given, else robust min/max)."""
    if vmin_k is None or vmax_k is None:
        vmin_k, vmax_k = _range(kelvin)
    img = _upscale(colorize(kelvin, vmin_k, vmax_k, cmap), min_height)
    return _titled(np.concatenate([img, colorbar(img.shape[0], vmin_k, vmax_k, cmap)], 1), title)


def _hstack(panels: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(p.shape[0] for p in panels)
    padded = [np.pad(p, ((0, h - p.shape[0]), (0, 0), (0, 0)), constant_values=255) for p in panels]
    spacer = np.full((h, gap, 3), 255, np.uint8)
    out = [padded[0]]
    for p in padded[1:]:
        out += [spacer, p]
    return np.concatenate(out, 1)


def thermal_strip(gt_k: np.ndarray, pred_k: np.ndarray, vmin_k: float | None = None,
                  vmax_k: float | None = None, cmap: str = "ironbow", err_max_k: float | None = None,
                  labels=("ground truth", "render", "|error|"), min_height: int = 240) -> np.ndarray:
    """GT | render (one shared °C scale) | absolute error in K (inferno), side by side."""
    if gt_k.shape != pred_k.shape:
        raise ValueError(f"GT {gt_k.shape} and render {pred_k.shape} differ in shape")
    if vmin_k is None or vmax_k is None:
        vmin_k, vmax_k = _range(gt_k)
    err = np.abs(np.asarray(pred_k, np.float64) - gt_k)
    if err_max_k is None:
        finite = err[np.isfinite(err)]
        err_max_k = float(max(np.percentile(finite, 99), 0.1)) if finite.size else 1.0
    gt_img, pred_img = (_upscale(colorize(x, vmin_k, vmax_k, cmap), min_height) for x in (gt_k, pred_k))
    err_img = _upscale(colorize(err, 0, err_max_k, "inferno"), min_height)
    h = gt_img.shape[0]
    return _hstack([_titled(gt_img, labels[0]), _titled(pred_img, labels[1]),
                    _titled(colorbar(h, vmin_k, vmax_k, cmap), " "),
                    _titled(err_img, labels[2]),
                    _titled(colorbar(h, 0, err_max_k, "inferno", unit="K", offset=0.0), " ")])


def rgb_strip(gt: np.ndarray, pred: np.ndarray, err_max: float = 0.25,
              labels=("ground truth", "render", "|error|"), min_height: int = 240) -> np.ndarray:
    """GT | render | per-pixel mean absolute error (inferno, 0..err_max) for RGB in [0, 1] or uint8."""
    to_float = lambda x: x.astype(np.float64) / 255 if x.dtype == np.uint8 else np.asarray(x, np.float64)
    a, b = to_float(gt), to_float(pred)
    if a.shape != b.shape:
        raise ValueError(f"GT {a.shape} and render {b.shape} differ in shape")
    as_u8 = lambda x: np.clip(np.round(x * 255), 0, 255).astype(np.uint8)
    err = np.abs(a - b).mean(axis=2)
    panels = [_upscale(as_u8(a), min_height), _upscale(as_u8(b), min_height),
              _upscale(colorize(err, 0, err_max, "inferno"), min_height)]
    h = panels[0].shape[0]
    return _hstack([_titled(p, t) for p, t in zip(panels, labels)]
                   + [_titled(colorbar(h, 0, err_max, "inferno", unit="|d|", offset=0.0), " ")])


def save_png(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an RGB uint8 image as PNG (creating folders)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: could not write image")
    return path
