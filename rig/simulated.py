"""The simulated rig: used by `rig capture` when no hardware is named, and by tests.

A scene gives, for any time, a temperature image (kelvin) and an RGB image of the same
moving objects. `SimThermalCamera` turns it into GigE-like frames (Mono16 counts in the
IRFormat in force, block ids, a device clock with its own offset and drift, NUC pauses);
`SimPhone` records QuickTime segments like an iPhone (1/600 time base, slightly variable
frame intervals, a wall clock off by `clock_offset_s` with `drift_ppm`, whole-second
creationdate) and drops each finished file into a folder, so the real drop-folder and sync
code recover the offset. An optional lamp (the sync box's) is drawn in a corner of both images.

Scenes: `WorldScene` (the default) renders the project's simulated world (`rig.sim`) at 1/5
size, 5 keyframes per second of its script, once, and blends and upscales them, because
full-size rendering at 30 Hz live is far too slow on the appliance's CPU (finer keyframes and
scale are options: blending keyframes far apart ghosts moving views, which pose recovery
cannot be graded on). `describe()` is the scene's ground truth (world, rig calibration, lamp
box) that the phone writes into the session with each file. `SyntheticScene` (seeded 2-D warm
objects, cheap) serves tests and `--sim-scene synthetic`.
"""
from __future__ import annotations

import datetime as dt
import logging
import math
import os
import queue
import threading
import time
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from rig.drivers import flir
from rig.drivers.gige import gvsp
from rig.drivers.gige.stream import Frame

log = logging.getLogger(__name__)

PHONE_TIME_BASE = Fraction(1, 600)
LAMP_BOX = (0.02, 0.02, 0.10, 0.10)      # x0, y0, x1, y1 as a fraction of the image


class Lamp:
    """Switch history of the sync-box lamp in scene time; `on(t)`, and `heat(t)` in 0..1 with
    the bulb's thermal lag `tau_s`."""

    def __init__(self, tau_s: float = 0.03):
        self.tau_s = tau_s
        self.switches: list[tuple[float, int]] = []

    def switch(self, state: int, t: float) -> None:
        self.switches.append((t, state))

    def on(self, t: float) -> bool:
        state = 0
        for ts, s in self.switches:
            if ts > t:
                break
            state = s
        return bool(state)

    def heat(self, t: float) -> float:
        """First-order thermal response of the bulb (0 cold .. 1 hot)."""
        level, last = 0.0, None
        for ts, s in self.switches:
            if ts > t:
                break
            if last is not None:
                level = last[1] + (level - last[1]) * math.exp(-(ts - last[0]) / self.tau_s)
            last = (ts, s)
        if last is None:
            return 0.0
        return last[1] + (level - last[1]) * math.exp(-(t - last[0]) / self.tau_s)


def _lamp_slices(h: int, w: int):
    x0, y0, x1, y1 = LAMP_BOX
    return slice(int(y0 * h), int(y1 * h)), slice(int(x0 * w), int(x1 * w))


class SyntheticScene:
    """Warm objects drifting over a background at varying speeds (seeded)."""

    def __init__(self, seed: int = 0, n_objects: int = 4, lamp: Lamp | None = None):
        rng = np.random.default_rng(seed)
        self.lamp = lamp
        self.obj = [{"f": rng.uniform(0.15, 0.6, 2), "ph": rng.uniform(0, 2 * np.pi, 4),
                     "amp": rng.uniform(0.15, 0.35, 2), "r": rng.uniform(0.06, 0.12),
                     "temp": rng.uniform(305, 330), "color": rng.uniform(60, 255, 3)}
                    for _ in range(n_objects)]
        self._grids: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def _grid(self, w: int, h: int):
        if (w, h) not in self._grids:
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            self._grids[(w, h)] = (xx / w, yy / h)
        return self._grids[(w, h)]

    def _weights(self, t: float, w: int, h: int):
        xx, yy = self._grid(w, h)
        for o in self.obj:
            # a jerky path: speed itself varies, so motion energy has structure to correlate
            cx = 0.5 + o["amp"][0] * math.sin(o["f"][0] * t + o["ph"][0] + 0.8 * math.sin(1.7 * o["f"][1] * t + o["ph"][2]))
            cy = 0.5 + o["amp"][1] * math.sin(o["f"][1] * t + o["ph"][1] + 0.8 * math.sin(1.3 * o["f"][0] * t + o["ph"][3]))
            yield o, np.exp(-((xx - cx) ** 2 + ((yy - cy) * h / w) ** 2) / (2 * o["r"] ** 2))

    def temperature(self, t: float, w: int, h: int) -> np.ndarray:
        xx, yy = self._grid(w, h)
        k = 293.0 + 3.0 * xx + 1.5 * yy
        for o, g in self._weights(t, w, h):
            k = k + (o["temp"] - 293.0) * g
        if self.lamp is not None:
            k[_lamp_slices(h, w)] += 60.0 * self.lamp.heat(t)
        return k.astype(np.float32)

    def rgb(self, t: float, w: int, h: int) -> np.ndarray:
        xx, yy = self._grid(w, h)
        img = np.empty((h, w, 3), np.float32)
        img[..., 0] = 40 + 60 * xx
        img[..., 1] = 50 + 40 * yy
        img[..., 2] = 70.0
        for o, g in self._weights(t, w, h):
            img += (o["color"] - img) * g[..., None]
        if self.lamp is not None and self.lamp.on(t):
            img[_lamp_slices(h, w)] = 255.0
        return np.clip(img, 0, 255).astype(np.uint8)


class WorldScene:
    """The project's simulated world (`rig.sim.make_world`) seen from rig 0. Keyframes are
    rendered at `render_scale` of the asked size, `key_hz` per second of the world's script
    (which ping-pongs over `duration_s`, so they are reused), blended linearly and upscaled."""

    def __init__(self, world, key_hz: float = 5.0, render_scale: float = 0.2, lamp: Lamp | None = None,
                 kind: str = "world"):
        self.world, self.key_hz, self.scale, self.lamp, self.kind = world, key_hz, render_scale, lamp, kind
        self.n_keys = int(round(world.duration_s * key_hz)) + 1
        self._cache: dict[tuple, np.ndarray] = {}

    def describe(self) -> dict:
        """Ground truth for grading a session: which world, how it was rendered, rig 0's true
        calibration (intrinsics at the reference size, `thermal_from_rgb`) and the lamp box."""
        rc = self.world.rig_config
        return {"kind": self.kind, "variant": self.world.variant, "seed": self.world.seed, "rig": 0,
                "key_hz": self.key_hz, "render_scale": self.scale,
                "rgb_intrinsics": asdict(rc.rgb), "thermal_intrinsics": asdict(rc.thermal),
                "thermal_from_rgb": rc.thermal_from_rgb.tolist(),
                "lamp_box": list(LAMP_BOX) if self.lamp is not None else None}

    def _render(self, kind: str, k: int, w: int, h: int) -> np.ndarray:
        key = (kind, k, w, h)
        if key not in self._cache:
            t = k / self.key_hz
            rw, rh = max(8, round(w * self.scale)), max(6, round(h * self.scale))
            cams = self.world.rig_config
            c2w_rgb, c2w_th = self.world.rig_pose(0, t)
            if kind == "thermal":
                i = cams.thermal.scaled(rw, rh)
                img = self.world.render_temperature(c2w_th, i.fx, i.fy, i.cx, i.cy, rw, rh, t)
            else:
                i = cams.rgb.scaled(rw, rh)
                img = self.world.render_rgb(c2w_rgb, i.fx, i.fy, i.cx, i.cy, rw, rh, t)
            self._cache[key] = np.asarray(img, np.float32)
        return self._cache[key]

    def prerender(self, sizes: dict[str, tuple[int, int]], until_s: float | None = None) -> None:
        """Render the keyframes of scene times up to `until_s` (default: all) now, for live
        capture. sizes: kind -> (w, h)."""
        last = self.n_keys - 1 if until_s is None else min(self.n_keys - 1, int(until_s * self.key_hz) + 2)
        for kind, (w, h) in sizes.items():
            for k in range(last + 1):
                self._render(kind, k, w, h)

    def _blend(self, kind: str, t: float, w: int, h: int) -> np.ndarray:
        s = self.world.scene_time(t) * self.key_hz
        k = min(int(s), self.n_keys - 2)
        a = s - k
        small = (1 - a) * self._render(kind, k, w, h) + a * self._render(kind, k + 1, w, h)
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)

    def temperature(self, t: float, w: int, h: int) -> np.ndarray:
        k = self._blend("thermal", t, w, h)
        if self.lamp is not None:
            k[_lamp_slices(h, w)] += 60.0 * self.lamp.heat(t)
        return k

    def rgb(self, t: float, w: int, h: int) -> np.ndarray:
        img = self._blend("rgb", t, w, h)
        if self.lamp is not None and self.lamp.on(t):
            img[_lamp_slices(h, w)] = 255.0
        return np.clip(img, 0, 255).astype(np.uint8)


class ScaledScene:
    """Render a scene at 1/`factor` of the asked size and upscale: live 30 Hz on a small CPU."""

    def __init__(self, scene, factor: int = 4):
        self.scene, self.factor = scene, factor

    def temperature(self, t: float, w: int, h: int) -> np.ndarray:
        k = self.scene.temperature(t, max(8, w // self.factor), max(6, h // self.factor))
        return cv2.resize(k, (w, h), interpolation=cv2.INTER_LINEAR)

    def rgb(self, t: float, w: int, h: int) -> np.ndarray:
        img = self.scene.rgb(t, max(8, w // self.factor), max(6, h // self.factor))
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)


SCENE_KINDS = ("world", "calibration", "synthetic")


def default_scene(seed: int = 0, lamp: Lamp | None = None, kind: str = "world", variant: str = "default",
                  key_hz: float = 5.0, render_scale: float = 0.2):
    """The project's simulated world (`rig.sim`) of `variant`, its heated checkerboard
    (kind "calibration", for `rig calibrate`), or the synthetic scene rendered at quarter size."""
    if kind == "synthetic":
        return ScaledScene(SyntheticScene(seed, lamp=lamp))
    from rig.sim import make_calibration_world, make_world
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown simulated scene {kind!r}; choose one of {', '.join(SCENE_KINDS)}")
    world = make_calibration_world(seed) if kind == "calibration" else make_world(variant, seed=seed)
    return WorldScene(world, key_hz=key_hz, render_scale=render_scale, lamp=lamp, kind=kind)


@dataclass
class SimClock:
    """A device clock: offset_s + (1 + drift) * (host_s - t0)."""
    offset_s: float
    drift_ppm: float
    t0: float = 0.0

    def __call__(self, host_s: float) -> float:
        return self.offset_s + (host_s - self.t0) * (1 + self.drift_ppm * 1e-6)


@dataclass
class SimThermalCamera:
    """A FLIR A700-like stream without the network: Frames as the GigE driver delivers them."""
    scene: object
    width: int = 640
    height: int = 480
    fps: float = 30.0
    ir_format: str = "TemperatureLinear10mK"
    clock: SimClock = field(default_factory=lambda: SimClock(5000.0, 20.0))
    tick_hz: int = 1_000_000_000
    nuc_period_s: float = 0.0       # 0: no NUC pauses
    nuc_duration_s: float = 0.4
    scene_t0: float = 0.0           # host s at scene time 0
    block_id: int = 1
    netd_k: float = 0.04            # temporal noise of the microbolometer (1 sigma)
    seed: int = 0

    def __post_init__(self):
        self._rng = np.random.default_rng(self.seed)

    def in_nuc(self, host_s: float) -> bool:
        if not self.nuc_period_s:
            return False
        ph = (host_s - self.scene_t0) % self.nuc_period_s
        return ph > self.nuc_period_s - self.nuc_duration_s

    def frame_at(self, host_s: float) -> Frame:
        kelvin = self.scene.temperature(host_s - self.scene_t0, self.width, self.height)
        if self.netd_k:
            kelvin = kelvin + self._rng.normal(0.0, self.netd_k, kelvin.shape).astype(np.float32)
        counts = flir.kelvin_to_counts(kelvin, self.ir_format)
        f = Frame(block_id=self.block_id, timestamp=int(self.clock(host_s) * self.tick_hz),
                  host_ns=int(host_s * 1e9), host_done_ns=int(host_s * 1e9),
                  pixel_format=gvsp.PIXEL_FORMATS["Mono16"], width=self.width, height=self.height,
                  data=counts.astype("<u2").tobytes(), complete=True,
                  meta={"ir_format": self.ir_format, "scale_k": flir.IR_FORMAT_SCALE_K.get(self.ir_format)})
        self.block_id = gvsp.next_block_id(self.block_id)
        return f

    def run(self, out: queue.Queue, stop: threading.Event) -> None:
        """Real time: put frames into `out` at `fps` until `stop` (sleeping through NUCs)."""
        period = 1 / self.fps
        t_next = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            if now < t_next:
                stop.wait(t_next - now)
                continue
            t_next += period
            if now - t_next > 1.0:
                t_next = now + period
            if not self.in_nuc(now):
                out.put(self.frame_at(now))


def write_quicktime(path: str | Path, frames, pts_s, creation_unix_s: float, codec: str = "libx264",
                    utc_offset_h: int = 2, fps_hint: int = 30) -> Path:
    """Encode (H, W, 3) uint8 RGB frames at presentation times `pts_s` (seconds from the file
    start) as an iPhone-like QuickTime movie: 1/600 track time base, whole-second local
    `com.apple.quicktime.creationdate` with UTC offset (FFmpeg writes such keys only with
    movflags=use_metadata_tags)."""
    tz = dt.timezone(dt.timedelta(hours=utc_offset_h))
    with av.open(str(path), "w", format="mov",
                 options={"movflags": "use_metadata_tags", "video_track_timescale": "600"}) as out:
        out.metadata["com.apple.quicktime.creationdate"] = \
            dt.datetime.fromtimestamp(int(creation_unix_s), tz).strftime("%Y-%m-%dT%H:%M:%S%z")
        out.metadata["com.apple.quicktime.make"] = "Apple"
        out.metadata["com.apple.quicktime.model"] = "iPhone (thermal4d simulated)"
        st = None
        for img, t in zip(frames, pts_s):
            if st is None:
                st = out.add_stream(codec, rate=fps_hint)
                st.height, st.width = img.shape[:2]
                st.pix_fmt = "yuv420p"
                st.time_base = st.codec_context.time_base = PHONE_TIME_BASE
                st.options = ({"preset": "veryfast", "crf": "20", "bf": "0"} if codec in ("libx264", "h264")
                              else {"preset": "ultrafast", "x265-params": "log-level=error:bframes=0"})
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            vf.pts, vf.time_base = round(t / PHONE_TIME_BASE), PHONE_TIME_BASE
            for pkt in st.encode(vf):
                out.mux(pkt)
        if st is None:
            raise ValueError(f"{path}: no frames to write")
        for pkt in st.encode():
            out.mux(pkt)
    return Path(path)


@dataclass
class SimPhone:
    """An iPhone recording segments into a drop folder (its own wall clock, VFR timing)."""
    scene: object
    drop_dir: Path
    width: int = 640                # the rig's phone video, cropped and downsampled to 4:3
    height: int = 480
    fps: float = 30.0
    segment_s: float = 10.0
    clock_offset_s: float = 0.137   # phone wall clock minus host wall clock
    drift_ppm: float = 50.0
    jitter_s: float = 0.002
    utc_offset_h: int = 2
    codec: str = "libx264"
    scene_t0: float = 0.0           # host monotonic s at scene time 0
    clock_t0: float = 0.0           # host monotonic s when the phone clock was clock_offset_s off
    realtime_minus_monotonic: float = 0.0
    seed: int = 0
    truth: list[dict] = field(default_factory=list)   # per file: true host start, nominal start
    stopped_at: float | None = None  # host s the recording was stopped (set before `stop`)

    def phone_unix(self, host_s: float) -> float:
        """Phone wall clock at host monotonic time `host_s`."""
        return (host_s + self.realtime_minus_monotonic + self.clock_offset_s
                + (host_s - self.clock_t0) * self.drift_ppm * 1e-6)

    def segment_times(self, start_host_s: float, duration_s: float, rng) -> np.ndarray:
        """Host times of the frames of one segment: regular in *phone* time, plus jitter."""
        n = int(duration_s * self.fps)
        phone_t = np.arange(n) / self.fps + rng.uniform(-self.jitter_s, self.jitter_s, n) * (np.arange(n) > 0)
        return start_host_s + phone_t / (1 + self.drift_ppm * 1e-6)

    def write_segment(self, name: str, host_times: np.ndarray) -> Path:
        """Encode frames at `host_times` into drop_dir/name (written hidden, then renamed)."""
        start = float(host_times[0])
        start_phone = self.phone_unix(start)
        final = Path(self.drop_dir) / name
        tmp = final.with_name(f".{name}.part")
        # PTS counts phone time since the segment started; the first frame is at 0
        pts = [(self.phone_unix(float(t)) - start_phone) for t in host_times]
        frames = (self.scene.rgb(float(t) - self.scene_t0, self.width, self.height) for t in host_times)
        write_quicktime(tmp, frames, pts, start_phone, codec=self.codec, utc_offset_h=self.utc_offset_h)
        self.truth.append({"file": name, "true_start_host_s": start,
                           "nominal_start_host_s": int(start_phone) - self.realtime_minus_monotonic,
                           "clock_offset_s": self.clock_offset_s, "drift_ppm": self.drift_ppm,
                           # frame k is at host start + pts_k / (1 + drift); scene time = host - t0
                           "scene_t0_host_s": self.scene_t0,
                           "scene": self.scene.describe() if hasattr(self.scene, "describe") else None})
        os.replace(tmp, final)     # after the truth entry, so the capture finds it with the file
        return final

    def run(self, stop: threading.Event, first_index: int = 1, gap_s: float = 0.3) -> None:
        """Real time: record segments back to back (a `gap_s` pause between files) until
        `stop`; frames are rendered when a segment ends, and the one in progress at `stop` is
        cut there and dropped too."""
        rng = np.random.default_rng(self.seed)
        idx = first_index
        start = time.monotonic()
        while True:
            times = self.segment_times(start, self.segment_s, rng)
            stopped = stop.wait(max(0.0, times[-1] - time.monotonic()))
            if stopped:
                times = times[times <= (self.stopped_at or time.monotonic())]
            if len(times) >= 2:
                self.write_segment(f"IMG_{idx:04d}.MOV", times)
                idx += 1
            if stopped:
                return
            start = times[-1] + gap_s
