"""Live training state published into the run folder, for the status page (`server/`) or anyone.

The trainer writes, the server only reads. Contract, ``RUN/live/`` (format "thermal4d-live", v1):

  status.json        the latest state, one JSON object, replaced whole on every update:
                     format, version, state ("starting" | "training" | "finishing" | "done" |
                     "failed"), method, phase (routing phase or null), iteration, iterations
                     (budget or null), minutes (wall-clock budget or null), progress [0, 1],
                     its (iterations/s, recent), elapsed_s (training time),
                     losses {modality: float}, psnr {modality: held-out dB}, gaussians,
                     roles {shared, rgb, thermal} (Gaussians per routing role), time_steps,
                     latest_time, events (divergences: [{iteration, reason, rolled_back_to,
                     lr_scale}], and drift warnings: {iteration, reason, warning: true}), schedule (what a converging run's schedule is doing, or null),
                     stop_reason (once done or failed), unix (time.time() of the write), wall_s
                     (s since the publisher started), pid. Missing values are absent or null,
                     never NaN.
  metrics.jsonl      history, one JSON object per line: unix, wall_s, iteration, elapsed_s,
                     progress, gaussians, roles, its, loss_<modality> (mean over the iterations
                     since the previous line), psnr_<modality> (only on lines where it was measured).
                     Each line is appended with one write; a reader ignores a last line without a
                     newline. Bounded: past `max_lines` lines the file is replaced (atomically) by a
                     thinned copy — every second line of the older three quarters, the newest
                     quarter kept whole — so it spans the whole run with recent points densest.
  renders.json       index of the published renders, replaced after the images it names:
                     {"version", "vmin_k", "vmax_k", "sets": {NAME: SET}} where NAME is "latest"
                     (the newest time step) or "t00", "t01", ... (the time-slider ring, sorted
                     by time) and SET = {"time" (normalised), "timestamp_s" (or null),
                     "iteration", "unix", "version", "files": [names present],
                     "width", "height" (of the kelvin image), "thermal_box" [x, y, w, h] (where the
                     kelvin image lies inside thermal.png, which adds a colourbar)}.
  render/NAME/rgb.png      RGB render, 8-bit
  render/NAME/thermal.png  temperature through the ironbow map with a °C colourbar (recon.viz)
  render/NAME/kelvin.npy   raw temperature, (H, W) little-endian uint16 in centikelvin
                           (kelvin = value * 0.01; 0 = no value), NumPy .npy v1

Every file except the metrics append is written to a hidden temporary file in the same folder
and moved into place with os.replace, so a reader sees the old or the new file, never a torn one.
Renders are refreshed by ring slot: each render round writes "latest" and the next ring slot.

Use: `LivePublisher(run_dir)` is the plain writer; `TrainingFeed(publisher)` turns a
`recon.train.Trainer` into those calls (throttled by wall clock so it costs little training
throughput):

    feed = TrainingFeed(LivePublisher(run_dir))
    ... after every trainer.step():  feed.on_step(trainer, stats)
    trainer.train(on_eval=feed.on_eval)     # optional: reuses the trainer's held-out PSNR
    feed.finish(trainer)                    # or feed.finish(trainer, state="failed")
"""
from __future__ import annotations

import io
import json
import math
import os
import threading
import time
from pathlib import Path

import numpy as np

FORMAT = "thermal4d-live"
VERSION = 1
KELVIN_SCALE = 0.01          # kelvin per count of kelvin.npy
MAX_SLOTS = 64


def atomic_write(path: Path, data: bytes) -> None:
    """Write bytes so readers see the old or the new file, never a part (temp + os.replace)."""
    tmp = path.parent / f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def jsonable(value):
    """Plain JSON types for dicts/lists/numpy/torch scalars; NaN and inf become None (JSON has
    neither, and a browser's JSON.parse rejects them)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item):      # numpy / torch scalars
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    raise TypeError(f"cannot publish {type(value).__name__} {value!r} as JSON")


def dumps(obj) -> bytes:
    return json.dumps(jsonable(obj), separators=(",", ":"), allow_nan=False).encode()


def png_bytes(image: np.ndarray) -> bytes:
    """(H, W, 3) uint8 -> PNG bytes (fast compression: these are rewritten every few seconds)."""
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, "PNG", compress_level=1)
    return buf.getvalue()


def kelvin_npy(kelvin: np.ndarray) -> bytes:
    """(H, W) kelvin -> .npy bytes of uint16 centikelvin (0 where not finite)."""
    k = np.asarray(kelvin, np.float64)
    counts = np.where(np.isfinite(k), np.clip(np.round(k / KELVIN_SCALE), 1, 65535), 0).astype("<u2")
    buf = io.BytesIO()
    np.save(buf, counts)
    return buf.getvalue()


def thin(lines: list, keep_recent: int) -> list:
    """Every second item of all but the last `keep_recent`, then those kept whole."""
    cut = max(len(lines) - keep_recent, 0)
    return lines[:cut][::2] + lines[cut:]


class LivePublisher:
    """Writes RUN/live/ (see the module docstring). Not thread-safe: call from one thread."""

    def __init__(self, run_dir: str | Path, max_lines: int = 2000):
        if max_lines < 8:
            raise ValueError(f"max_lines must be >= 8, got {max_lines}")
        self.dir = Path(run_dir) / "live"
        (self.dir / "render").mkdir(parents=True, exist_ok=True)
        self.max_lines = max_lines
        self.start_unix = time.time()
        self._start = time.monotonic()
        self._metrics = self.dir / "metrics.jsonl"
        self._lines = self._existing_lines()
        self._index = {"version": 0, "vmin_k": None, "vmax_k": None, "sets": {}}
        old = self.dir / "renders.json"
        if old.exists():     # a resumed run keeps showing its previous renders until new ones come
            try:
                index = json.loads(old.read_text())
            except ValueError:
                index = None
            if isinstance(index, dict) and isinstance(index.get("sets"), dict) and isinstance(index.get("version"), int):
                self._index = index

    def _existing_lines(self) -> int:
        if not self._metrics.exists():
            return 0
        with open(self._metrics, "rb") as f:
            return sum(1 for line in f if line.endswith(b"\n"))

    def _stamp(self, d: dict) -> dict:
        return {**d, "unix": round(time.time(), 3), "wall_s": round(time.monotonic() - self._start, 3)}

    def status(self, d: dict) -> None:
        """Replace status.json with `d` (keys in the module docstring) plus format, unix, wall_s, pid."""
        atomic_write(self.dir / "status.json",
                     dumps({"format": FORMAT, "version": VERSION, **self._stamp(d), "pid": os.getpid()}))

    def metric(self, d: dict) -> None:
        """Append one history line (`d` plus unix, wall_s); thin the file past max_lines."""
        line = dumps(self._stamp(d)) + b"\n"
        fd = os.open(self._metrics, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line)        # one write: a reader sees the whole line or a torn tail it skips
        finally:
            os.close(fd)
        self._lines += 1
        if self._lines > self.max_lines:
            with open(self._metrics, "rb") as f:
                lines = [x for x in f.read().splitlines(keepends=True) if x.endswith(b"\n")]
            kept = thin(lines, self.max_lines // 4)
            atomic_write(self._metrics, b"".join(kept))
            self._lines = len(kept)

    def renders(self, time_: float, rgb: np.ndarray | None, kelvin: np.ndarray | None,
                vmin_k: float, vmax_k: float, slot: int | None = None, iteration: int | None = None,
                timestamp_s: float | None = None) -> str:
        """Publish one render set at normalised time `time_`: rgb (H, W, 3) uint8 and/or kelvin
        (H, W) (either may be None for a one-modality method); the colourised temperature uses
        [vmin_k, vmax_k]. slot None = "latest", else the time-slider slot 0..63. Returns its name."""
        if rgb is None and kelvin is None:
            raise ValueError("renders(): give rgb, kelvin or both")
        if slot is not None and not 0 <= slot < MAX_SLOTS:
            raise ValueError(f"renders(): slot must be in 0..{MAX_SLOTS - 1}, got {slot}")
        if not (math.isfinite(vmin_k) and math.isfinite(vmax_k) and vmax_k > vmin_k):
            raise ValueError(f"renders(): need finite vmin_k < vmax_k, got {vmin_k}, {vmax_k}")
        name = "latest" if slot is None else f"t{slot:02d}"
        folder = self.dir / "render" / name
        folder.mkdir(parents=True, exist_ok=True)
        meta = {"time": float(time_), "timestamp_s": timestamp_s, "iteration": iteration,
                "unix": round(time.time(), 3), "files": []}
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
                raise ValueError(f"renders(): rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
            atomic_write(folder / "rgb.png", png_bytes(rgb))
            meta["files"].append("rgb.png")
        if kelvin is not None:
            from recon.viz import thermal_image
            kelvin = np.asarray(kelvin)
            if kelvin.ndim != 2:
                raise ValueError(f"renders(): kelvin must be (H, W), got shape {kelvin.shape}")
            picture = thermal_image(kelvin, vmin_k, vmax_k)
            scale = picture.shape[0] // kelvin.shape[0]
            atomic_write(folder / "thermal.png", png_bytes(picture))
            atomic_write(folder / "kelvin.npy", kelvin_npy(kelvin))
            meta["files"] += ["thermal.png", "kelvin.npy"]
            meta.update(width=int(kelvin.shape[1]), height=int(kelvin.shape[0]),
                        thermal_box=[0, 0, int(kelvin.shape[1] * scale), int(kelvin.shape[0] * scale)])
        self._index["version"] += 1
        meta["version"] = self._index["version"]
        self._index.update(vmin_k=float(vmin_k), vmax_k=float(vmax_k))
        self._index["sets"][name] = meta
        atomic_write(self.dir / "renders.json", dumps(self._index))
        return name


class TrainingFeed:
    """Publishes a `recon.train.Trainer` through a LivePublisher.

    on_step is cheap (a clock check) except when a period is due: status every `status_every_s`,
    a history line every `metric_every_s` (with held-out PSNR every `psnr_every_s`), and a render
    round (latest time step + the next of `ring` time-slider slots) every `render_every_s`. None of
    this draws random numbers, so training is the same with or without it."""

    def __init__(self, publisher: LivePublisher, ring: int = 8, status_every_s: float = 0.5,
                 metric_every_s: float = 2.0, psnr_every_s: float = 10.0, render_every_s: float = 3.0):
        if not 0 <= ring <= MAX_SLOTS:
            raise ValueError(f"ring must be in 0..{MAX_SLOTS}, got {ring}")
        self.pub = publisher
        self.ring = ring
        self.periods = {"status": status_every_s, "metric": metric_every_s, "psnr": psnr_every_s,
                        "render": render_every_s}
        self._due = dict.fromkeys(self.periods, 0.0)      # monotonic time each job is next due
        self._loss_sum: dict[str, float] = {}
        self._loss_n = 0
        self._losses: dict[str, float] = {}
        self._psnr: dict[str, float] = {}
        self._its_mark = (time.monotonic(), 0)
        self._its = None
        self._next_slot = 0

    # ------------------------------------------------------------------ trainer hooks
    def on_step(self, trainer, stats: dict) -> None:
        """Call after every trainer.step() with the dict it returned."""
        for k, v in stats.items():
            if k.startswith("loss_"):
                self._loss_sum[k] = self._loss_sum.get(k, 0.0) + float(v)
        self._loss_n += 1
        now = time.monotonic()
        if now >= self._due["psnr"] and now >= self._due["metric"]:
            self._psnr = trainer.holdout_psnr()
            self._metric(trainer, psnr=True)
        elif now >= self._due["metric"]:
            self._metric(trainer, psnr=False)
        if now >= self._due["render"]:
            self.publish_renders(trainer)
        if now >= self._due["status"]:
            self.publish_status(trainer)

    def on_eval(self, trainer, record: dict) -> None:
        """Pass as Trainer.train(on_eval=...): reuses the PSNR the trainer just measured."""
        self._psnr = {k[5:]: v for k, v in record.items() if k.startswith("psnr_")}
        self._metric(trainer, psnr=True)
        self.publish_status(trainer)

    def finish(self, trainer, state: str = "done") -> None:
        """Last status ("done" or "failed"), a last history line and every render slot refreshed."""
        if state == "done":
            self._psnr = trainer.holdout_psnr()
            self._metric(trainer, psnr=True)
            self.publish_renders(trainer, all_slots=True)
        self.publish_status(trainer, state=state)

    # ------------------------------------------------------------------ what gets written
    def _schedule(self, job: str) -> None:
        self._due[job] = time.monotonic() + self.periods[job]

    def _measure_its(self, trainer) -> float | None:
        t, it = self._its_mark
        now = time.monotonic()
        if trainer.iteration > it and now > t:
            self._its = (trainer.iteration - it) / (now - t)
            self._its_mark = (now, trainer.iteration)
        return self._its

    def _metric(self, trainer, psnr: bool) -> None:
        if self._loss_n:
            self._losses = {k: s / self._loss_n for k, s in self._loss_sum.items()}
            self._loss_sum, self._loss_n = {}, 0
        record = {"iteration": trainer.iteration, "elapsed_s": round(trainer.elapsed, 3),
                  "progress": round(trainer.progress(), 5), "gaussians": trainer.model.num_gaussians,
                  "roles": trainer.counts(), "its": self._measure_its(trainer),
                  **{k: round(v, 6) for k, v in self._losses.items()}}
        if psnr:
            record.update({f"psnr_{m}": round(v, 3) for m, v in self._psnr.items()})
            self._schedule("psnr")
        self.pub.metric(record)
        self._schedule("metric")

    def publish_status(self, trainer, state: str = "training") -> None:
        from recon.dtg import routing
        cfg = trainer.cfg
        phase = routing.phase(cfg.routing, trainer.progress()) if cfg.model.routing else None
        times = trainer.scene.times
        # live training (recon.live.follow) schedules progress itself: the configured budget is not its end
        scheduled = getattr(trainer, "progress_fn", None) is not None
        self.pub.status({
            "state": state, "method": cfg.method, "phase": phase, "iteration": trainer.iteration,
            "iterations": None if cfg.minutes or scheduled else cfg.iterations,
            "minutes": None if scheduled else cfg.minutes,
            "progress": round(trainer.progress(), 5), "its": self._its, "elapsed_s": round(trainer.elapsed, 3),
            "losses": {k[5:]: v for k, v in self._losses.items()}, "psnr": self._psnr,
            "gaussians": trainer.model.num_gaussians, "roles": trainer.counts(),
            "time_steps": len(times), "latest_time": max(times) if times else None,
            "events": list(getattr(trainer, "events", [])),
            "stop_reason": trainer.stop_reason() if state in ("done", "failed") and not scheduled else None,
            "schedule": self._schedule_note(trainer)})
        self._schedule("status")

    @staticmethod
    def _schedule_note(trainer) -> str | None:
        """'holding: held-out still improving' while a converging run's schedule holds."""
        sched = getattr(trainer, "schedule", None)
        if sched is None or not sched.converge or getattr(trainer, "progress_fn", None) is not None:
            return None
        if sched.holding and not sched.released:
            return f"holding while held-out PSNR improves (best {sched.best:.2f} dB)"
        return sched.stop_reason

    def ring_times(self, trainer) -> list[float]:
        times = trainer.scene.times
        if not times or not self.ring:
            return []
        return [float(t) for t in np.linspace(min(times), max(times), self.ring)]

    def publish_renders(self, trainer, all_slots: bool = False) -> None:
        """Render the newest time step ("latest") and the next ring slot (or every slot)."""
        times = trainer.scene.times
        if not times:
            return
        self._render_set(trainer, max(times), None)
        ring = self.ring_times(trainer)
        slots = range(len(ring)) if all_slots else [self._next_slot % len(ring)] if ring else []
        for slot in slots:
            self._render_set(trainer, ring[slot], slot)
        if ring and not all_slots:
            self._next_slot = (self._next_slot + 1) % len(ring)
        self._schedule("render")

    def _render_set(self, trainer, t: float, slot: int | None) -> None:
        from recon.render import render_frame
        scene, rgb, kelvin, stamp = trainer.scene, None, None, None
        for m in trainer.cfg.model.modalities:
            views = scene.test[m] or scene.train[m]
            if not views:
                continue
            view = min(views, key=lambda v: abs(v.time - t))       # what the rig saw near t
            image = render_frame(trainer.model, m, t, view.camera)
            stamp = view.frame.timestamp_s if stamp is None else stamp
            if m == "rgb":
                rgb = (image.clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8)
            else:
                kelvin = scene.kelvin(image[..., 0]).numpy()
        if rgb is not None or kelvin is not None:
            self.pub.renders(t, rgb, kelvin, scene.k_min, scene.k_max, slot=slot,
                             iteration=trainer.iteration, timestamp_s=stamp)
