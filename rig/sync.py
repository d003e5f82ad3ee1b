"""Put thermal and phone frames on one time line (host monotonic seconds) and pair them.

- Thermal: device timestamps -> host time by a line through the low-latency envelope of
  (device time, host receive time); a constant transport delay remains (sub-ms on a LAN).
- Phone: each file's frames sit at `creationdate + PTS`, but the phone clock is off (and its
  creation date has 1 s resolution), so each file gets an offset: by cross-correlating its
  motion energy with the thermal temperature-change energy (no hardware needed), or, when a
  sync box recorded lamp switches, with the switch train on the host clock.
- Phone drift: with markers, from the switches themselves. Each switch shows in the phone's
  lamp cell between two frames, which bounds the file's offset at that moment to one frame
  interval; the line (offset + slope * time) through all these bounds is pinned far tighter
  than any one frame (the centre of the feasible lines is taken). Without markers, from
  offsets measured in windows along each file. Either way a drift is kept only where it stands
  3 sigma out of its uncertainty. Window offsets about the model give the residual.
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
MIN_WINDOW_S = 2.0             # files shorter than 2 windows get half-file windows, down to this
MIN_DRIFT_SIGMAS = 3.0         # keep a phone drift only when it stands out of its uncertainty
MAX_DRIFT = 1e-3               # 1000 ppm: beyond any quartz; a bigger fit is a wrong peak
DRIFT_STEP = 1e-6              # slope grid of the marker drift fit (1 ppm)
SWITCH_SLACK_S = 0.001         # widens each switch's bounds: PTS rounding (1/600 s base: +-0.83 ms)
MIN_SWITCHES = 6               # per file, for the marker drift fit
DRIFT_SD_KEEP = 50e-6          # a marker drift fit this precise is kept even if not 3 sigma from 0


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


def fit_clock(device_s: np.ndarray, host_s: np.ndarray, bins: int = 24, fixed_rate: bool = False) -> ClockFit:
    """Line through the lowest-latency points: split the (N,) samples into `bins` spans of
    device time, keep the sample with the smallest latency of each, fit through those.
    (Receive latency only ever adds, so the minima trace the clock relation.)
    fixed_rate: the device clock runs at true rate (a PTP slave): only the offset is fitted, as
    the median of those minima, so arrival jitter cannot tilt the line."""
    device_s, host_s = np.asarray(device_s, float), np.asarray(host_s, float)
    d0 = float(device_s[0])
    x = device_s - d0
    if len(x) < 2 or np.ptp(x) == 0:
        return ClockFit(1.0, float(np.min(host_s - x)), d0, 0.0)
    lat = host_s - x                       # latency + offset, rate ~ 1
    edges = np.linspace(x.min(), x.max() + 1e-9, min(bins, len(x) // 3 + 1) + 1)
    idx = [int(np.flatnonzero(sel)[np.argmin(lat[sel])])
           for a, b in zip(edges[:-1], edges[1:]) if (sel := (x >= a) & (x < b)).any()]
    if fixed_rate:
        rate, off = 1.0, float(np.median(lat[idx]))
    elif len(idx) >= 2:
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
    offset_s: float                 # host - nominal at ref_s
    correlation: float
    windows: list[tuple[float, float]] = field(default_factory=list)   # (nominal t, local offset)
    switches: int = 0               # lamp switches that bound the marker drift fit


@dataclass
class SyncResult:
    method: str                     # "markers", "xcorr" or "none"
    thermal_clock: dict | None
    files: list[FileSync]
    drift_ppm: float                # phone clock rate - host clock rate (phone fast: > 0)
    residual_ms: float | None       # RMS of windowed offsets about the fitted model
    thermal_gaps: list[dict]
    rgb_offset_ms: float | None     # mean file offset (the phone clock error, as seen by sync)
    drift_sd_ppm: float | None = None   # 1 sigma of the drift fit (None: no fit was possible)
    drift_method: str = "none"      # "markers" (switch bounds), "windows" or "none" (no fit)
    residual_note: str | None = None    # why residual_ms is None

    def as_dict(self) -> dict:
        return asdict(self)

    def rgb_host_s(self, file: str, nominal_s: np.ndarray) -> np.ndarray:
        """Host s of a file's nominal times (creationdate + PTS): phone seconds run 1 + drift
        times as fast as host seconds."""
        fs = next(f for f in self.files if f.file == file)
        n = np.asarray(nominal_s, float)
        return fs.ref_s + fs.offset_s + (n - fs.ref_s) / (1 + self.drift_ppm * 1e-6)


def lamp_channel(t: np.ndarray, e: np.ndarray, ref_t: np.ndarray, ref_e: np.ndarray, offset: float) -> int:
    """The motion-energy cell that follows the lamp: the channel of e (N, C), at nominal times t
    (N,), best correlated with the single-channel marker reference shifted by `offset`."""
    ref = np.interp(t + offset, ref_t, np.asarray(ref_e, float).reshape(len(ref_t), -1)[:, 0])
    return int(np.argmax([_corr(e[:, [c]], ref[:, None]) for c in range(e.shape[1])]))


def switch_bounds(t: np.ndarray, change: np.ndarray, switches: np.ndarray, channel: int, offset: float,
                  ref: float, slope: float = 0.0, valid: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds on a phone file's offset (host - nominal) from lamp switches at host times
    `switches` (M,). A frame shows the lamp as it is at the frame's time, so a switch at host m
    seen in the difference of frames k-1 and k (change[k], the spike in the lamp's `channel`)
    gives m - t[k] <= offset(x) <= m - t[k-1] at x = its nominal time - ref; a switch during the
    exposure can spread over two differences, so a neighbour at >= 25 % of the spike widens the
    bounds to both. t (N,) nominal frame times; change (N, C) per-frame change energy; `offset`
    + `slope` * x places switches roughly (a frame either side is searched). Switches whose lamp
    cell does not spike clearly (half the median spike), or with another switch within three
    frames, are left out. -> (x, lo, hi), each (K,) seconds."""
    t = np.asarray(t, float)
    c = np.asarray(change, float).reshape(len(t), -1)[:, channel]
    dt = np.diff(t, prepend=np.nan)
    period = float(np.nanmedian(dt)) if len(t) > 2 else 0.0
    ok = (dt > 0) & (dt < 1.5 * period)                     # interval k ends at frame k
    if valid is not None:
        v = np.asarray(valid, bool)
        ok &= v & np.roll(v, 1)
    empty = (np.zeros(0),) * 3
    if not ok.any():
        return empty
    sw = np.sort(np.asarray(switches, float))
    gap = np.diff(sw)
    lone = np.ones(len(sw), bool)
    lone[1:] &= gap > 3 * period
    lone[:-1] &= gap > 3 * period
    nominal = sw - offset - slope * (sw - offset - ref)
    during = lone & (nominal > t[0]) & (nominal <= t[-1])
    found = []                                               # (m, nominal, first k, last k, spike)
    for m, n in zip(sw[during], nominal[during]):
        k0 = int(np.searchsorted(t, n))
        cand = [k for k in (k0 - 1, k0, k0 + 1) if 1 <= k < len(t) and ok[k]]
        if not cand:
            continue
        k = max(cand, key=lambda j: c[j])
        near = [j for j in (k - 1, k + 1) if 1 <= j < len(t) and ok[j] and c[j] >= 0.25 * c[k]]
        found.append((m, n, min([k, *near]), max([k, *near]), c[k]))
    if not found:
        return empty
    m, n, k_first, k_last, spike = (np.array(col) for col in zip(*found))
    k_first, k_last = k_first.astype(int), k_last.astype(int)
    if np.median(spike) <= 3 * np.median(c[ok]):            # no lamp in view: nothing to bound
        return empty
    keep = spike >= 0.5 * np.median(spike)
    m, n, k_first, k_last = m[keep], n[keep], k_first[keep], k_last[keep]
    return n - ref, m - t[k_last] - SWITCH_SLACK_S, m - t[k_first - 1] + SWITCH_SLACK_S


def _trimmed_band(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, slopes: np.ndarray, trim: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Offsets o with lo <= o + slope * x <= hi for all but `trim` bounds on each side, per
    slope (S,). -> (lowest o (S,), highest o (S,))."""
    a = np.sort(lo[None, :] - slopes[:, None] * x[None, :], axis=1)[:, -1 - trim]
    b = np.sort(hi[None, :] - slopes[:, None] * x[None, :], axis=1)[:, trim]
    return a, b


def _fewest_trim(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, slopes: np.ndarray) -> int | None:
    """Fewest bounds to drop on each side (up to a tenth) so that some slope passes the rest."""
    for trim in range(len(x) // 10 + 1):
        a, b = _trimmed_band(x, lo, hi, slopes, trim)
        if (b >= a).any():
            return trim
    return None


def fit_between_bounds(bounds: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
                       ) -> tuple[float, float, list[float]] | None:
    """Lines o_f + slope * x, one offset per file and a common slope, through every file's
    (x, lo, hi) bounds (`switch_bounds`). Under uniform priors the lines consistent with the
    bounds are equally likely, so the estimate is the centre (mean) of that set: the slope's
    weight is the product over files of the widths of their feasible offsets. Up to a tenth
    of a file's bounds on each side may be dropped (a misread switch), the fewest that leave
    it feasible. A loose fit (sd > DRIFT_SD_KEEP) within MIN_DRIFT_SIGMAS of a feasible zero
    gives slope 0. -> (slope, its sd, per-file offsets at the slope), None when no file has
    MIN_SWITCHES bounds or the slope is not pinned inside +-MAX_DRIFT."""
    slopes = np.arange(-MAX_DRIFT, MAX_DRIFT + DRIFT_STEP / 2, DRIFT_STEP)
    bands = []                        # per file: (x, lo, hi, bounds dropped per side) or None
    for x, lo, hi in bounds:
        trim = _fewest_trim(x, lo, hi, slopes) if len(x) else None
        bands.append(None if trim is None else (x, lo, hi, trim))
    if not any(b is not None and len(b[0]) >= MIN_SWITCHES for b in bands):
        return None
    weight = np.ones(len(slopes))
    for band in bands:
        if band is not None:
            a, b = _trimmed_band(band[0], band[1], band[2], slopes, band[3])
            weight *= np.clip(b - a, 0.0, None)
    if weight.sum() <= 0 or weight[0] > 0 or weight[-1] > 0:
        return None
    w = weight / weight.sum()
    slope = float((w * slopes).sum())
    sd = float(np.sqrt((w * (slopes - slope) ** 2).sum()))
    if sd > DRIFT_SD_KEEP and abs(slope) < MIN_DRIFT_SIGMAS * sd and weight[len(slopes) // 2] > 0:
        slope = 0.0                   # not measurable here, and zero drift fits the bounds too
    return slope, sd, [float(np.mean(_trimmed_band(b[0], b[1], b[2], np.array([slope]), b[3])))
                       if b is not None else float("nan") for b in bands]


def window_offsets(ref_t, ref_e, t: np.ndarray, e: np.ndarray, model) -> list[tuple[float, float]]:
    """Offsets of windows along one file (midpoint times t (N,), energies e (N, C)), WINDOW_S
    long or, in a shorter file, half of it (at least MIN_WINDOW_S: a short file still shows its
    scatter), overlapping by half, each searched within 30 ms of `model(time)`. -> [(window
    middle, offset)] of windows that correlate (> 0.3)."""
    span = float(t[-1] - t[0]) if len(t) else 0.0
    win = min(WINDOW_S, span / 2)
    if win < MIN_WINDOW_S:
        return []
    n_win = max(2, int(span // (win / 2)) - 1)
    out = []
    for k in range(n_win):
        a = t[0] + k * (span - win) / (n_win - 1)
        sel = (t >= a) & (t <= a + win)
        c = model(a + win / 2)
        o, cw = align(ref_t, ref_e, t[sel], e[sel], c - 0.03, c + 0.03)
        if np.isfinite(o) and cw > 0.3:
            out.append((float(a + win / 2), o))
    return out


def window_drift(rows: np.ndarray) -> tuple[float, float | None]:
    """Common slope through the origin of (K, 2) rows (time from file middle, window offset -
    file offset), kept only if it stands MIN_DRIFT_SIGMAS above its standard error.
    -> (slope, its standard error; None with fewer than 3 rows)."""
    if len(rows) < 3:
        return 0.0, None
    x, y = rows.T
    sxx = float((x * x).sum())
    if sxx <= 0:
        return 0.0, None
    slope = float((x * y).sum() / sxx)
    se = float(np.sqrt(((y - slope * x) ** 2).sum() / (len(x) - 1) / sxx))
    return (slope if MIN_DRIFT_SIGMAS * se < abs(slope) < MAX_DRIFT else 0.0), se


def file_offsets(files: dict[str, dict], ref_t: np.ndarray, ref_e: np.ndarray,
                 search_s: tuple[float, float] = (-0.6, 1.5), switches: np.ndarray | None = None
                 ) -> tuple[list[FileSync], float, float | None, float | None, str]:
    """Per-file offsets against a reference energy on the host clock (whole file, held at its
    middle), a common phone drift, and the residual. files: name -> {"nominal_start_s", "t"
    (nominal frame times), "motion", "valid"}. search_s: offsets considered, from the nominal
    start: the creation date is truncated to whole seconds (true start 0..1 s after it) and a
    phone clock kept by NTP is off by well under 0.6 s; a symmetric +-1.5 s let a short file
    lock onto the wrong lamp pulse. switches: lamp switch host times (M,) when ref_e is their
    marker signal: the drift and offsets then come from the switch bounds (`fit_between_bounds`),
    else from windows along the files. The residual is the RMS of window offsets about the
    model. -> (per-file results, drift ppm, its sd ppm or None, residual ms or None, drift
    method "markers" / "windows" / "none")."""
    out, signals = [], []
    for name, f in files.items():
        t, e = energy_rate(f["t"], f["motion"], f.get("valid"))
        off, c = align(ref_t, ref_e, t, e, *search_s)
        mid = float((t[0] + t[-1]) / 2) if len(t) else f["nominal_start_s"]
        out.append(FileSync(name, f["nominal_start_s"], mid, off, c))
        signals.append((t, e))
    slope, sd, method = 0.0, None, "none"
    if switches is not None:
        channels = [lamp_channel(t, e, ref_t, ref_e, fs.offset_s) if np.isfinite(fs.offset_s) and len(t) > 10
                    else None for fs, (t, e) in zip(out, signals)]
        for _ in range(2):            # a second pass places switches with the drift found
            bounds = [(np.zeros(0),) * 3 if ch is None else
                      switch_bounds(f["t"], f["motion"], switches, ch, fs.offset_s, fs.ref_s, slope, f.get("valid"))
                      for fs, f, ch in zip(out, files.values(), channels)]
            fit = fit_between_bounds(bounds)
            if fit is None:
                break
            slope, sd, offsets = fit
            method = "markers"
            for fs, b, o in zip(out, bounds, offsets):
                fs.switches = len(b[0])
                fs.offset_s = o if np.isfinite(o) else fs.offset_s
    rows = []                         # (time from file middle, window offset - file offset)
    for fs, (t, e) in zip(out, signals):
        if np.isfinite(fs.offset_s):
            fs.windows = window_offsets(ref_t, ref_e, t, e,
                                        lambda x, fs=fs: fs.offset_s + slope * (x - fs.ref_s))
            rows += [(w - fs.ref_s, o - fs.offset_s) for w, o in fs.windows]
    rows = np.array(rows).reshape(-1, 2)
    if method == "none" and len(rows):
        slope, sd = window_drift(rows)
        method = "none" if sd is None else "windows"
    residual = (float(np.sqrt(((rows[:, 1] - slope * rows[:, 0]) ** 2).mean()) * 1e3)
                if len(rows) >= 2 else None)
    drift_ppm = -slope / (1 + slope) * 1e6 + 0.0    # offset slope -> phone clock rate error (no -0)
    return out, drift_ppm, None if sd is None else sd * 1e6, residual, method


def residual_note(files: dict[str, dict], windows: int) -> str | None:
    """Why a sync has no residual (None if it has one: 2 or more window offsets)."""
    if windows >= 2:
        return None
    if not files:
        return "no phone video to sync"
    longest = max((np.ptp(f["t"]) if len(f["t"]) > 1 else 0.0) for f in files.values())
    if longest < 2 * MIN_WINDOW_S:
        return (f"phone files too short for a residual: the longest is {longest:.1f} s, windows of "
                f"{MIN_WINDOW_S:g} s need {2 * MIN_WINDOW_S:g} s")
    return f"{windows} window of the phone files correlated with the reference; 2 are needed"


def thermal_gaps(times: np.ndarray, dropped_before: np.ndarray, period_s: float | None = None) -> list[dict]:
    """Intervals longer than 1.5 frame periods: drops (block ids missing) or pauses (NUC).
    period_s: the camera's set frame period, the one capture's nuc pause events use (None: the
    median interval, which late frames on a busy host push up so the two lists could differ)."""
    t = np.asarray(times, float)
    if len(t) < 3:
        return []
    dt = np.diff(t)
    period = period_s or np.median(dt)
    out = []
    for k in np.nonzero(dt > 1.5 * period)[0]:
        d = int(dropped_before[k + 1])
        out.append({"after": int(k), "gap_s": float(dt[k]), "dropped": d,
                    "kind": "dropped" if d else "pause (NUC)"})
    return out


def synchronise(thermal: list[dict], rgb: list[dict], events: list[dict], tick_hz: float,
                host_epoch: dict, ptp_slave: bool = False, frame_period_s: float | None = None) -> SyncResult:
    """Sync a session's records (as `rig.session.Session` holds them). ptp_slave: the thermal
    camera's clock followed a PTP grandmaster (session.json thermal.ptp.status "Slave").
    frame_period_s: the thermal camera's set frame period, if known (see `thermal_gaps`)."""
    th = [r for r in thermal if r.get("device_ts")]
    clock = None
    th_t = np.zeros(0)
    if len(th) >= 2:
        clock = fit_clock(np.array([r["device_ts"] for r in th], float) / tick_hz,
                          np.array([r["host_ns"] for r in th], float) / 1e9, fixed_rate=ptp_slave)
        th_t = clock(np.array([r["device_ts"] for r in th], float) / tick_hz)
    gaps = thermal_gaps(th_t, np.array([r.get("dropped_before", 0) for r in th]), frame_period_s)
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
    results, drift, drift_sd, residual, drift_method = [], 0.0, None, None, "none"
    note = None if files else "no phone video to sync"
    if files and len(th_t) < 3:
        note = "too few thermal frames with device timestamps to sync"
    if files and len(th_t) >= 3:
        if len(switches) >= 2:
            period = float(np.median(np.diff(th_t)))
            ref_t, ref_e = marker_signal(switches, period, th_t[0] - 2, th_t[-1] + 2)
            method = "markers"
        else:
            ref_t, ref_e = energy_rate(th_t, [r.get("change", 0.0) for r in th],
                                       [r.get("complete", True) for r in th])
            method = "xcorr"
        results, drift, drift_sd, residual, drift_method = file_offsets(
            files, ref_t, ref_e, switches=switches if method == "markers" else None)
        note = residual_note(files, sum(len(f.windows) for f in results))
    offsets = [f.offset_s for f in results if np.isfinite(f.offset_s)]
    return SyncResult(method, asdict(clock) if clock else None, results, drift, residual, gaps,
                      float(np.mean(offsets) * 1e3) if offsets else None, drift_sd, drift_method, note)


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
    rate = session.meta.get("thermal", {}).get("frame_rate")
    return synchronise(session.thermal, session.rgb, events, tick_hz, session.meta["host_clock"],
                       ptp_slave=ptp_slave(session.meta), frame_period_s=1.0 / rate if rate else None)


def ptp_slave(meta: dict) -> bool:
    """session.json says the thermal camera's clock followed a PTP grandmaster."""
    return (meta.get("thermal", {}).get("ptp") or {}).get("status") == "Slave"
