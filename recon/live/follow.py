"""`recon run SESSION --follow`: train while `rig capture` is still appending to SESSION.

Poses are re-solved, not frozen: every `refresh_s` seconds of new capture a background thread runs
`recon prepare` on the frames committed so far (the session reader never exposes half-written
frames) into RUN/live_data/vK, and aligns that reconstruction to the previous one by a similarity fitted
on the camera path where they overlap, so the model's world frame never jumps. The
trainer then continues on the grown scene (Trainer.replace_scene): same Gaussians, optimizer and
statistics; densification keeps running.

Time is capture seconds over a horizon (the planned duration when the session says it, else twice
the span seen), not the dataset's normalised time, which would shift every frame as the capture
grows. When the capture outgrows the horizon, the horizon doubles and the time embedding is
extended with its learned rows kept where they were (Trainer.extend_time).

Schedule: while capturing, progress rises to `capture_progress` (routing learns with the early
prior, densification on, learning rates high); once the capture is closed and its final
reconstruction loaded, progress runs to 1 over `after_iterations` (specialisation, routing
freeze, decay), then the run finishes like `recon run`. A capture that dies without closing
(no new frame for `stall_s`, no closed.json) is treated as ended, and an unexpected error in the
pose thread ends the run the same way: the follower never waits forever.
"""
from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.config import TrainConfig
from recon.data import load_dataset
from recon.data.ply import read_points_ply, write_points_ply
from recon.scene import Scene
from recon.train.trainer import Trainer
from rig.session import open_session


class FollowError(RuntimeError):
    """The capture ended before any reconstruction could be made; `data_dir` holds the last
    attempt's prepare report."""

    def __init__(self, message: str, data_dir: Path | None):
        super().__init__(message)
        self.data_dir = data_dir


@dataclass
class FollowOptions:
    refresh_s: float = 15.0          # re-solve poses after this much new capture
    after_iterations: int = 1500     # iterations after the capture ends
    min_capture_s: float = 4.0       # wait for this much capture before the first reconstruction
    steps_per_s: float = 1.0         # time steps picked per second of capture ...
    max_steps: int = 90              # ... at most (pycolmap takes ~1 s per 640x480 frame here)
    capture_progress: float = 0.3    # schedule position held while capturing
    warmup_iterations: int = 300     # iterations to reach it
    poll_s: float = 1.0
    stall_s: float = 30.0            # no new thermal frame for this long and no closed.json: the
                                     # capture died (kill -9, power); train on what it left


def session_span_s(session) -> float:
    """Seconds of thermal capture committed so far."""
    ns = [r["host_ns"] for r in session.thermal if "host_ns" in r]
    return (max(ns) - min(ns)) / 1e9 if len(ns) > 1 else 0.0


def planned_duration_s(session) -> float | None:
    meta = session.meta or {}
    for key in ("requested_duration_s", "duration_s", "planned_duration_s"):
        if isinstance(meta.get(key), (int, float)) and meta[key] > 0:
            return float(meta[key])
    return None


# ------------------------------------------------------------------ keeping one world frame
def similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama: s, R, t minimising |dst - (s R src + t)|. src, dst: (M, 3), M >= 3."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    r = u @ d @ vt
    s = float(np.trace(np.diag(sig) @ d) / max((a ** 2).sum() / len(src), 1e-12))
    return s, r, mu_d - s * r @ mu_s


def interpolate_centres(reference: tuple[np.ndarray, np.ndarray], times: np.ndarray) -> np.ndarray:
    """Camera centres of the reference path (times (M,), centres (M, 3)) at `times` (K,)."""
    ts, cs = reference
    return np.stack([np.interp(times, ts, cs[:, i]) for i in range(3)], axis=1)


def align_dataset(data_dir: Path, reference: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    """Rewrite data_dir's poses and points into the reference frame. reference: the RGB camera
    path (timestamps (M,), centres (M, 3)) of the previous reconstruction, already in the world
    frame; the new frames that fall inside its time span are matched to it by interpolation
    (each re-run of SfM picks its own frames). Returns this dataset's path, aligned."""
    path = data_dir / "transforms.json"
    meta = json.loads(path.read_text())
    rgb = sorted(((float(f["timestamp_s"]), np.asarray(f["transform_matrix"])[:3, 3])
                  for f in meta["frames"] if f["modality"] == "rgb"), key=lambda tc: tc[0])
    times, centres = np.array([t for t, _ in rgb]), np.stack([c for _, c in rgb])
    if reference is None:
        return times, centres
    inside = (times >= reference[0][0]) & (times <= reference[0][-1])
    if inside.sum() < 3:
        raise RuntimeError(f"{data_dir}: only {int(inside.sum())} frames overlap the previous reconstruction")
    s, r, t = similarity(centres[inside], interpolate_centres(reference, times[inside]))
    for f in meta["frames"]:
        m = np.asarray(f["transform_matrix"], dtype=np.float64)
        m[:3, :3] = r @ m[:3, :3]
        m[:3, 3] = s * r @ m[:3, 3] + t
        f["transform_matrix"] = m.tolist()
    ply = data_dir / meta.get("ply_file_path", "points3d.ply")
    if ply.exists():
        xyz, col = read_points_ply(ply)
        write_points_ply(ply, s * xyz @ r.T + t, col)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(meta, indent=1))
    tmp.replace(path)
    return times, s * centres @ r.T + t


class Reconstructor(threading.Thread):
    """Background `recon prepare` of the growing session; finished datasets go to `ready`."""

    def __init__(self, session_dir: Path, out: Path, opts: FollowOptions, log, prepare_options: dict):
        super().__init__(daemon=True)
        self.session_dir, self.out, self.opts, self.log = session_dir, out, opts, log
        self.prepare_options = prepare_options
        self.ready: queue.Queue = queue.Queue()
        self.stop_event = threading.Event()
        self.reference: tuple[np.ndarray, np.ndarray] | None = None
        self.last_error: tuple[str, Path] | None = None     # why the newest attempt failed, and where

    def run(self) -> None:
        try:
            self._follow_session()
        except Exception as exc:     # a dead thread must not leave the trainer waiting forever
            self.log(f"live poses: stopped by an unexpected error: {exc!r}")
            self.last_error = (f"unexpected error {exc!r}", None)
            self.ready.put((None, True, 0.0))

    def _follow_session(self) -> None:
        from recon.prepare import PrepareError, prepare_session

        session = open_session(self.session_dir)
        next_due, version = self.opts.min_capture_s, 0
        frames, last_growth = -1, time.monotonic()
        while not self.stop_event.is_set():
            session.refresh()
            if len(session.thermal) != frames:
                frames, last_growth = len(session.thermal), time.monotonic()
            span, closed = session_span_s(session), session.closed
            if not closed and time.monotonic() - last_growth > self.opts.stall_s:
                self.log(f"live poses: no new frame for {self.opts.stall_s:.0f} s and no closed.json; "
                         f"treating the capture as ended at {span:.0f} s")
                closed = True
            if not (closed or span >= next_due):
                self.stop_event.wait(self.opts.poll_s)
                continue
            steps = int(min(self.opts.max_steps, max(8, span * self.opts.steps_per_s)))
            target = self.out / f"v{version:03d}"
            t0 = time.perf_counter()
            try:
                prepare_session(self.session_dir, target, progress=None, frames=steps, **self.prepare_options)
                self.reference = align_dataset(target, self.reference)
                self.ready.put((target, closed, span))
                self.log(f"live poses: v{version} from {span:.0f} s of capture, {steps} steps, "
                         f"{time.perf_counter() - t0:.0f} s{' (final)' if closed else ''}")
                if closed:
                    return
                version += 1
                next_due = span + self.opts.refresh_s
            except (PrepareError, RuntimeError) as exc:
                self.last_error = (str(exc), target)
                if closed:
                    self.log(f"live poses: failed on the whole capture ({exc})")
                    self.ready.put((None, True, span))
                    return
                # e.g. the phone's first video has not landed yet: try again soon
                self.log(f"live poses: not yet ({exc}); retrying with more capture")
                next_due = span + self.opts.min_capture_s


def follow(session_dir: Path, run_dir: Path, cfg: TrainConfig, opts: FollowOptions, log,
           prepare_options: dict | None = None, on_eval=None, on_step=None) -> tuple[Trainer, Path]:
    """Train while the session grows; return the trainer and the final dataset folder."""
    recon_thread = Reconstructor(session_dir, run_dir / "live_data", opts, log, prepare_options or {})
    recon_thread.start()
    session = open_session(session_dir)
    horizon = planned_duration_s(session)
    trainer, data_dir, closed, end_iteration = None, None, False, None

    def scene_for(path: Path) -> Scene:
        return Scene(load_dataset(path), time_of=lambda f: min(float(f.timestamp_s) / horizon, 1.0))

    def schedule(tr: Trainer) -> float:
        p_cap = opts.capture_progress
        if end_iteration is None:
            return min(p_cap, p_cap * tr.iteration / max(opts.warmup_iterations, 1))
        after = tr.iteration - end_iteration
        return 1.0 if after >= opts.after_iterations else p_cap + (1 - p_cap) * after / opts.after_iterations

    try:
        while True:
            try:
                path, is_final, span = recon_thread.ready.get(timeout=0.0 if trainer else opts.poll_s)
            except queue.Empty:
                path = None
                is_final = False
            else:
                if path is None and trainer is None:
                    why, where = recon_thread.last_error or ("no attempt finished", None)
                    raise FollowError(f"{session_dir}: the capture ended before poses could be recovered "
                                      f"(last attempt: {why})", where)
                if path is not None:
                    horizon = horizon or 2.0 * max(span, 1.0)
                    while span > horizon * 1.001:
                        horizon *= 2
                        if trainer:
                            trainer.extend_time(2)
                            log(f"live: capture outgrew the time horizon; now {horizon:.0f} s")
                    scene = scene_for(path)
                    data_dir = path
                    if trainer is None:
                        trainer = Trainer(cfg, scene, run_dir, log=log)
                        trainer.progress_fn = schedule
                        trainer.announce()
                    else:
                        trainer.replace_scene(scene)
                        log(f"live: {len(scene.times)} time steps, {trainer.model.num_gaussians} Gaussians, "
                            f"iteration {trainer.iteration}")
                if is_final:
                    closed = True
                    end_iteration = trainer.iteration
                    log(f"live: capture finished at iteration {end_iteration}; {opts.after_iterations} more iterations")
            if trainer is None:
                continue
            stats = trainer.tick(on_eval)
            if on_step:
                on_step(trainer, stats)
            if closed and trainer.done():
                break
    finally:
        recon_thread.stop_event.set()
    if trainer is not None:
        trainer.save_checkpoint(run_dir / "checkpoints" / "latest.pt")
    return trainer, data_dir
