"""Put thermal and phone frames on one time line (host monotonic seconds) and pair them.

- Thermal: device timestamps -> host time by a line through the low-latency envelope of
  (device time, host receive time); a constant transport delay remains (sub-ms on a LAN).
- Phone: each file's frames sit at `creationdate + PTS`, but the phone clock is off (and its
  creation date has 1 s resolution), so each file gets an offset: by cross-correlating its
  motion energy with the thermal temperature-change energy (no hardware needed), or, when a
  sync box recorded lamp switches, with the switch train on the host clock. Offsets measured
  in windows along each file give the phone's drift (common slope) and the residual.
- Energy signals are frame differences divided by the frame interval, placed at interval
  midpoints; intervals longer than 1.5 frame periods (drops, NUC pauses) are left out.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field

import numpy as np

log = logging.getLogger(__name__)

THUMB_SIZE = (64, 48)          # images are compared at this size for the energy signals
GRID_S = 0.002
WINDOW_S = 6.0
MIN_DRIFT_SIGMAS = 3.0         # fit a phone drift only when it stands out of the window noise
MAX_DRIFT = 1e-3               # 1000 ppm: beyond any quartz; a bigger fit is a wrong peak


def thumbnail(img: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) image -> (48, 64) float32 grey, for change-energy signals."""
    import cv2
    a = np.asarray(img, np.float32)
    if a.ndim == 3:
        a = a.mean(axis=2)
    return cv2.resize(a, THUMB_SIZE, interpolation=cv2.INTER_AREA)


CELLS = 5                      # change energy is kept per cell of a CELLS x CELLS grid


def change_energy(prev: np.ndarray | None, cur: np.ndarray) -> list[float]:
    """Mean absolute difference of two thumbnails in each cell of a CELLS x CELLS grid (row-major),
    zeros without a previous one. Per-cell signals tell apart objects moving in different
    parts of the view, which a single number mixes up."""
    if prev is None:
        return [0.0] * CELLS * CELLS
    d = np.abs(cur - prev)
    h, w = d.shape
    return [float(d[i * h // CELLS:(i + 1) * h // CELLS, j * w // CELLS:(j + 1) * w // CELLS].mean())
            for i in range(CELLS) for j in range(CELLS)]


@dataclass
class ClockFit:
    """host_s = rate * (device_s - device0) + offset."""
    rate: float
    offset: float
    device0: float
    rms_ms: float

    def __call__(self, device_s):
        return self.rate * (np.asarray(device_s, float) - self.device0) + self.offset


def fit_clock(device_s: np.ndarray, host_s: np.ndarray, bins: int = 24) -> ClockFit:
    """Line through the lowest-latency points: split the (N,) samples into `bins` spans of
    device time, keep the sample with the smallest latency of each, fit through those.
    (Receive latency only ever adds, so the minima trace the clock relation.)"""
    device_s, host_s = np.asarray(device_s, float), np.asarray(host_s, float)
    d0 = float(device_s[0])
    x = device_s - d0
    if len(x) < 2 or np.ptp(x) == 0:
        return ClockFit(1.0, float(np.min(host_s - x)), d0, 0.0)
    lat = host_s - x                       # latency + offset, rate ~ 1
    edges = np.linspace(x.min(), x.max() + 1e-9, min(bins, len(x) // 3 + 1) + 1)
    idx = [int(np.flatnonzero(sel)[np.argmin(lat[sel])])
           for a, b in zip(edges[:-1], edges[1:]) if (sel := (x >= a) & (x < b)).any()]
    if len(idx) >= 2:
        rate, off = np.polyfit(x[idx], host_s[idx], 1)
    else:
        rate, off = 1.0, float(lat.min())
    r = host_s[idx] - (rate * x[idx] + off)
    return ClockFit(float(rate), float(off), d0, float(np.sqrt(np.mean(r ** 2)) * 1e3))


def energy_rate(times: np.ndarray, change: np.ndarray, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame change energy (change[k] between frames k-1 and k) -> (midpoint times,
    energy per second), dropping long intervals and invalid frames."""
    t = np.asarray(times, float)
    dt = np.diff(t)
    if len(dt) == 0:
        return np.zeros(0), np.zeros(0)
    period = np.median(dt)
    ok = (dt > 0) & (dt < 1.5 * period)
    if valid is not None:
        v = np.asarray(valid, bool)
        ok &= v[1:] & v[:-1]
    mid = (t[1:] + t[:-1]) / 2
    e = np.asarray(change, float)
    e = e.reshape(len(e), -1)
    return mid[ok], e[1:][ok] / dt[ok, None]


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of (N, C) signals: the mean over matching channels, or, against a
    single-channel reference, the best channel (the cell where the lamp is)."""
    if len(a) < 10:
        return -1.0
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    den = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    ok = den > 0
    if not ok.any():
        return -1.0
    r = (a * b).sum(axis=0)[ok] / den[ok]
    return float(r.max() if b.shape[1] == 1 and a.shape[1] > 1 else r.mean())


def _interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp for each column of fp (N, C) -> (len(x), C)."""
    return np.stack([np.interp(x, xp, fp[:, c]) for c in range(fp.shape[1])], axis=1)


def _zscore(x: np.ndarray) -> np.ndarray:
    sd = x.std(axis=0)
    return (x - x.mean(axis=0)) / np.where(sd > 0, sd, 1.0)


def align(ref_t, ref_e, t, e, lo: float, hi: float) -> tuple[float, float]:
    """Offset o in [lo, hi] that best explains e(t) ~ ref_e(t + o): coarse search by
    cross-correlation on a 2 ms grid, then Pearson correlation refined to 0.25 ms with a
    parabola through the peak. ref_e (M,) or (M, C'), e (N,) or (N, C). -> (offset s, corr)."""
    ref_t, ref_e, t, e = (np.asarray(x, float) for x in (ref_t, ref_e, t, e))
    ref_e, e = ref_e.reshape(len(ref_e), -1), e.reshape(len(e), -1)
    if ref_e.shape[1] not in (1, e.shape[1]):
        raise ValueError(f"reference has {ref_e.shape[1]} channels, signal {e.shape[1]}")
    if len(t) < 3 or len(ref_t) < 3:
        return float("nan"), -1.0
    grid = np.arange(t[0], t[-1], GRID_S)
    sig = _interp(grid, t, e)
    ref_grid = np.arange(grid[0] + lo, grid[-1] + hi + GRID_S / 2, GRID_S)
    ref = _zscore(_interp(ref_grid, ref_t, ref_e))
    ref[(ref_grid < ref_t[0]) | (ref_grid > ref_t[-1])] = 0.0
    z = _zscore(sig)
    xc = np.stack([np.correlate(ref[:, min(c, ref.shape[1] - 1)], z[:, c], "valid")
                   for c in range(z.shape[1])], axis=1) / len(z)
    xc = xc.max(axis=1) if ref.shape[1] == 1 and z.shape[1] > 1 else xc.mean(axis=1)
    best = lo + int(np.argmax(xc)) * GRID_S

    def score(o: float) -> float:
        inside = (grid + o >= ref_t[0]) & (grid + o <= ref_t[-1])
        if inside.mean() < 0.5:
            return -1.0
        return _corr(sig[inside], _interp(grid[inside] + o, ref_t, ref_e))

    fine = np.arange(best - 2 * GRID_S, best + 2 * GRID_S + 1e-9, 0.00025)
    fs = np.array([score(o) for o in fine])
    k = int(np.argmax(fs))
    if 0 < k < len(fine) - 1:
        y0, y1, y2 = fs[k - 1:k + 2]
        den = y0 - 2 * y1 + y2
        shift = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        return float(fine[k] + shift * 0.00025), float(fs[k])
    return float(fine[k]), float(fs[k])


def marker_signal(switch_host_s: np.ndarray, period_s: float, t0: float, t1: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Reference energy of lamp switches as frame differences see them: a box one frame
    period wide around each switch. -> (times, energy) on a 1 ms grid."""
    t = np.arange(t0, t1, 0.001)
    e = np.zeros_like(t)
    for m in switch_host_s:
        e[np.abs(t - m) <= period_s / 2] = 1.0
    return t, e


@dataclass
class FileSync:
    file: str
    nominal_start_s: float          # host s where creationdate + pts = 0 would put it
    ref_s: float                    # nominal host s (file middle) at which offset_s holds
    offset_s: float                 # add to nominal times (plus drift * (t - ref_s))
    correlation: float
    windows: list[tuple[float, float]] = field(default_factory=list)   # (nominal t, local offset)


@dataclass
class SyncResult:
    method: str                     # "markers", "xcorr" or "none"
    thermal_clock: dict | None
    files: list[FileSync]
    drift_ppm: float
    residual_ms: float | None       # RMS of windowed offsets about the fitted model
    thermal_gaps: list[dict]
    rgb_offset_ms: float | None     # mean file offset (the phone clock error, as seen by sync)

    def as_dict(self) -> dict:
        return asdict(self)

    def rgb_host_s(self, file: str, nominal_s: np.ndarray) -> np.ndarray:
        fs = next(f for f in self.files if f.file == file)
        n = np.asarray(nominal_s, float)
        return n + fs.offset_s + self.drift_ppm * 1e-6 * (n - fs.ref_s)


def file_offsets(files: dict[str, dict], ref_t: np.ndarray, ref_e: np.ndarray,
                 search_s: tuple[float, float] = (-0.6, 1.5)) -> tuple[list[FileSync], float, float | None]:
    """Per-file offsets against a reference energy on the host clock (whole file, held at its
    middle), then a common drift from offsets in windows along each file, kept only if it
    stands out of their scatter. files: name -> {"nominal_start_s", "t" (nominal frame times),
    "motion", "valid"}. search_s: offsets considered, from the nominal start: the creation date is
    truncated to whole seconds (true start 0..1 s after it) and a phone clock kept by NTP is off
    by well under 0.6 s; a symmetric +-1.5 s let a short file lock onto the wrong lamp pulse.
    -> (per-file results, drift ppm, residual ms)."""
    out = []
    rows = []                         # (time from file middle, window offset - file offset)
    for name, f in files.items():
        t, e = energy_rate(f["t"], f["motion"], f.get("valid"))
        off, c = align(ref_t, ref_e, t, e, *search_s)
        mid = float((t[0] + t[-1]) / 2) if len(t) else f["nominal_start_s"]
        fs = FileSync(name, f["nominal_start_s"], mid, off, c)
        if np.isfinite(off) and len(t) and t[-1] - t[0] >= WINDOW_S:
            span = t[-1] - t[0]
            n_win = max(2, int(span // (WINDOW_S / 2)) - 1)
            for k in range(n_win):
                a = t[0] + k * (span - WINDOW_S) / (n_win - 1)
                sel = (t >= a) & (t <= a + WINDOW_S)
                o, cw = align(ref_t, ref_e, t[sel], e[sel], off - 0.03, off + 0.03)
                if np.isfinite(o) and cw > 0.3:
                    fs.windows.append((float(a + WINDOW_S / 2), o))
                    rows.append((a + WINDOW_S / 2 - mid, o - off))
        out.append(fs)
    drift, residual = 0.0, None
    if len(rows) >= 2:
        x, y = np.array(rows).T
        slope = float((x * y).sum() / (x * x).sum()) if (x * x).sum() > 0 else 0.0
        resid = y - slope * x
        se = float(np.sqrt((resid ** 2).sum() / max(len(x) - 1, 1) / max((x * x).sum(), 1e-12)))
        if len(rows) >= 3 and abs(slope) > MIN_DRIFT_SIGMAS * se and abs(slope) < MAX_DRIFT:
            drift = slope
        else:                         # not measurable from these windows: no drift term
            resid = y
        residual = float(np.sqrt((resid ** 2).mean()) * 1e3)
    return out, drift * 1e6, residual


def thermal_gaps(times: np.ndarray, dropped_before: np.ndarray) -> list[dict]:
    """Intervals longer than 1.5 frame periods: drops (block ids missing) or pauses (NUC)."""
    t = np.asarray(times, float)
    if len(t) < 3:
        return []
    dt = np.diff(t)
    period = np.median(dt)
    out = []
    for k in np.nonzero(dt > 1.5 * period)[0]:
        d = int(dropped_before[k + 1])
        out.append({"after": int(k), "gap_s": float(dt[k]), "dropped": d,
                    "kind": "dropped" if d else "pause (NUC)"})
    return out


def synchronise(thermal: list[dict], rgb: list[dict], events: list[dict], tick_hz: float,
                host_epoch: dict) -> SyncResult:
    """Sync a session's records (as `rig.session.Session` holds them)."""
    th = [r for r in thermal if r.get("device_ts")]
    clock = None
    th_t = np.zeros(0)
    if len(th) >= 2:
        clock = fit_clock(np.array([r["device_ts"] for r in th], float) / tick_hz,
                          np.array([r["host_ns"] for r in th], float) / 1e9)
        th_t = clock(np.array([r["device_ts"] for r in th], float) / tick_hz)
    gaps = thermal_gaps(th_t, np.array([r.get("dropped_before", 0) for r in th]))
    files: dict[str, dict] = {}
    realtime_minus_mono = (host_epoch["realtime_ns"] - host_epoch["monotonic_ns"]) / 1e9
    file_info = {e["file"]: e for e in events if e.get("event") == "rgb_file"}
    for r in rgb:
        f = files.setdefault(r["file"], {"t": [], "motion": [], "nominal_start_s": None})
        if f["nominal_start_s"] is None:
            info = {**file_info.get(r["file"], {}), **r}
            if info.get("creation_unix_s") is not None:
                f["nominal_start_s"] = info["creation_unix_s"] - realtime_minus_mono
            else:                   # no creation date: the file ended when it arrived
                f["nominal_start_s"] = info.get("host_ns", 0) / 1e9 - info.get("duration_s", 0.0)
        f["t"].append(f["nominal_start_s"] + r["pts_s"])
        f["motion"].append(r["motion"])
    switches = np.array([e["host_s"] for e in events if e.get("event") == "marker" and "host_s" in e])
    method = "none"
    results, drift, residual = [], 0.0, None
    if files and len(th_t) >= 3:
        if len(switches) >= 2:
            period = float(np.median(np.diff(th_t)))
            ref_t, ref_e = marker_signal(switches, period, th_t[0] - 2, th_t[-1] + 2)
            method = "markers"
        else:
            ref_t, ref_e = energy_rate(th_t, [r.get("change", 0.0) for r in th],
                                       [r.get("complete", True) for r in th])
            method = "xcorr"
        results, drift, residual = file_offsets(files, ref_t, ref_e)
    offsets = [f.offset_s for f in results if np.isfinite(f.offset_s)]
    return SyncResult(method, asdict(clock) if clock else None, results, drift, residual, gaps,
                      float(np.mean(offsets) * 1e3) if offsets else None)


def pair_frames(thermal_s: np.ndarray, rgb_s: np.ndarray, max_dt_s: float) -> list[tuple[int, int, float]]:
    """Nearest RGB frame for each thermal frame, if within max_dt_s. -> (thermal i, rgb j, dt s)."""
    rgb_s = np.asarray(rgb_s, float)
    if len(rgb_s) == 0:
        return []
    order = np.argsort(rgb_s)
    srt = rgb_s[order]
    out = []
    for i, t in enumerate(np.asarray(thermal_s, float)):
        k = int(np.searchsorted(srt, t))
        cands = [c for c in (k - 1, k) if 0 <= c < len(srt)]
        c = min(cands, key=lambda c: abs(srt[c] - t))
        if abs(srt[c] - t) <= max_dt_s:
            out.append((i, int(order[c]), float(srt[c] - t)))
    return out


def synchronise_session(session) -> SyncResult:
    """`synchronise` on what a `rig.session.Session` has committed so far. Markers are put on
    the host clock with the sync box's last clock estimate (a `syncbox_clock` event)."""
    events = list(session.events)
    clocks = [e for e in events if e.get("event") == "syncbox_clock"]
    if clocks:
        rate, offset = clocks[-1]["rate"], clocks[-1]["offset"]
        events = [{**e, "host_s": rate * e["box_us"] / 1e6 + offset}
                  if e.get("event") == "marker" and "box_us" in e else e for e in events]
    tick_hz = session.meta.get("thermal", {}).get("tick_hz", 1e9)
    return synchronise(session.thermal, session.rgb, events, tick_hz, session.meta["host_clock"])
