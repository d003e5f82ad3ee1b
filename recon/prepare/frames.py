"""Which frames of a session go into the dataset: pairing on the synced clock, then one sharp RGB
frame per time bin.

Pairs are the phone frames with a complete thermal frame within half a thermal frame period
(`rig.sync.pair_frames` on host-clock times). The paired span is cut into `n` equal time bins and
each bin keeps its sharpest phone frame (variance of the Laplacian of the grey image): evenly
spread time steps for the deformation model, and the least motion-blurred frame of each for SfM.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rig.calibrate import frame_times
from rig.sync import pair_frames, synchronise_session


class PrepareError(RuntimeError):
    """The session cannot become a trustworthy dataset; the message says why and what to do."""


@dataclass(frozen=True)
class Pair:
    rgb_index: int          # record index in session.rgb
    thermal_index: int      # record index in session.thermal
    rgb_s: float            # host-clock seconds
    thermal_s: float


@dataclass
class Timeline:
    pairs: list[Pair]       # in RGB time order
    t0: float               # span of the pairs (host s); dataset time 0 and 1
    t1: float
    sync: dict              # method, residual_ms, rgb_offset_ms


@dataclass
class Selected:
    pair: Pair
    image: np.ndarray       # (H, W, 3) uint8 RGB
    sharpness: float
    brightness: float       # mean grey level in [0, 1]


def session_timeline(session) -> Timeline:
    """Sync the session and pair each phone frame with the nearest complete thermal frame."""
    sync = synchronise_session(session)
    if sync.method == "none" or not session.rgb or len(session.thermal) < 3:
        raise PrepareError(f"{session.path}: thermal and phone frames could not be synchronised "
                           f"({len(session.thermal)} thermal frames, {len(session.rgb)} phone frames, sync "
                           f"method {sync.method!r}); recapture with both cameras running for the whole take")
    t_th, t_rgb = frame_times(session, sync)
    th_ok = np.array([i for i, r in enumerate(session.thermal) if r.get("complete", True)])
    rgb_ok = np.flatnonzero(np.isfinite(t_rgb))
    period = float(np.median(np.diff(np.sort(t_th[th_ok])))) if len(th_ok) > 1 else 1 / 30
    raw = pair_frames(t_rgb[rgb_ok], t_th[th_ok], period / 2) if len(th_ok) else []
    pairs = sorted((Pair(int(rgb_ok[i]), int(th_ok[j]), float(t_rgb[rgb_ok[i]]), float(t_th[th_ok[j]]))
                    for i, j, _ in raw), key=lambda p: p.rgb_s)
    if len(pairs) < 3:
        raise PrepareError(f"{session.path}: only {len(pairs)} phone frames have a thermal frame within "
                           f"{period / 2 * 1e3:.0f} ms (sync method {sync.method}); check `rig info` for "
                           f"dropped frames and recapture")
    times = [p.rgb_s for p in pairs] + [p.thermal_s for p in pairs]
    return Timeline(pairs, min(times), max(times),
                    {"method": sync.method, "residual_ms": sync.residual_ms, "rgb_offset_ms": sync.rgb_offset_ms,
                     "pair_dt_ms_median": float(np.median([abs(p.rgb_s - p.thermal_s) for p in pairs]) * 1e3)})


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian of a (H, W) uint8 image: lower = blurrier."""
    return float(cv2.Laplacian(gray, cv2.CV_32F).var())


def select_frames(session, timeline: Timeline, n: int, progress=None) -> list[Selected]:
    """The sharpest paired phone frame in each of `n` equal time bins over the paired span
    (decodes every paired phone frame once; keeps one image per bin)."""
    pairs = timeline.pairs
    times = np.array([p.rgb_s for p in pairs])
    edges = np.linspace(times[0], times[-1], min(n, len(pairs)) + 1)
    bin_of = {p.rgb_index: min(int(np.searchsorted(edges, p.rgb_s, side="right")) - 1, len(edges) - 2)
              for p in pairs}
    by_index = {p.rgb_index: p for p in pairs}
    best: dict[int, Selected] = {}
    done = 0
    for frame in session.iter_rgb():
        pair = by_index.get(frame.index)
        if pair is None:
            continue
        gray = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
        b = bin_of[frame.index]
        s = sharpness(gray)
        if b not in best or s > best[b].sharpness:
            best[b] = Selected(pair, frame.image, s, float(gray.mean() / 255))
        done += 1
        if progress and done % 100 == 0:
            progress(f"decoded {done}/{len(pairs)} paired phone frames")
    return [best[b] for b in sorted(best)]
