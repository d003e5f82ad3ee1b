"""`rig capture`: record a session from the thermal camera, the phone drop folder and the sync box.

Threads: the thermal source (GigE receiver or the simulated camera) fills a queue; a writer
commits frames to the session in group commits; a phone thread takes finished files from
the drop folder, decodes their PTS and motion energy, and links them in; the main thread
pings the sync box, prints a progress line and re-estimates sync every few seconds.
"""
from __future__ import annotations

import datetime as dt
import logging
import platform
import queue
import shutil
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from server.cli_options import add_serve_arguments, serve_from_args
from rig.cli_format import HelpFormatter, positive_float
from rig.drivers import flir
from rig.drivers.gige import GvcpError, gvsp
from rig.drivers.gige.features import GenicamXmlError
from rig.drivers.syncbox import SyncBoxError
from rig.drivers.gige.stream import Frame, StreamConfig
from rig.drivers.phone import PHOTO_SUFFIXES, DropFolder, probe_video, pts_drops
from rig.info import session_info
from rig.session import SessionWriter, open_session
from rig.sim.tabletop import VARIANTS
from rig.sync import change_energy, synchronise_session, thumbnail

log = logging.getLogger(__name__)


@dataclass
class CaptureConfig:
    duration_s: float = 60.0
    out: Path | None = None                 # default: sessions/YYYYmmdd-HHMMSS
    camera: str | None = None               # gige://HOST[:PORT]
    phone_drop: Path | None = None
    syncbox: str | None = None              # serial port
    ir_format: str = "TemperatureLinear10mK"
    packet_size: int = 1500
    marker_period_s: float = 1.0            # sync-box lamp pulse period (more switches, finer sync)
    marker_on_s: float = 0.5
    settle_s: float = 1.0                   # drop-folder quiet time before a file counts
    sim_segment_s: float = 10.0             # simulated phone: seconds per movie file
    sim_phone_offset_s: float = 0.137       # simulated phone clock error ...
    sim_phone_drift_ppm: float = 50.0       # ... and drift, for sync to recover
    sim_lamp: bool = True                   # simulated rig: a sync-box lamp in view of both cameras
    sim_scene: str = "world"                # "world" (rig.sim), "calibration" (its checkerboard), "synthetic"
    sim_variant: str = "default"            # rig.sim variant of the "world" scene
    sim_keyframe_hz: float = 5.0            # world scenes: keyframes per second, blended in between
    sim_render_scale: float = 0.2           # world scenes: keyframes rendered at this size, upscaled
    seed: int = 0
    sync_every_s: float = 5.0
    progress: bool = True


@dataclass
class CaptureStats:
    thermal_frames: int = 0
    thermal_incomplete: int = 0
    thermal_dropped: int = 0                # frames lost entirely (block ids missing)
    thermal_resent: int = 0                 # packets recovered by PACKETRESEND
    rgb_frames: int = 0
    rgb_files: int = 0
    rgb_dropped: int = 0                    # judged by PTS gaps
    rgb_span_s: float = 0.0                 # summed PTS span of the videos (for their frame rate)
    markers: int = 0
    errors: list[str] = field(default_factory=list)
    gige_stream: dict | None = None         # receiver counters (packets, resends, duplicates, ...)


def default_out() -> Path:
    return Path("sessions") / dt.datetime.now().strftime("%Y%m%d-%H%M%S")


def progress_line(elapsed_s: float, duration_s: float, streams: dict, markers: int,
                  residual_ms: float | None, offset_ms: float | None) -> str:
    """The `rig capture` status line. streams as `rig info` has them: {"thermal": {"frames",
    "fps", "incomplete", "dropped", "resent" (packets, optional)}, "rgb": {"frames", "files",
    "fps", "dropped"}}."""
    th, rgb = streams["thermal"], streams["rgb"]
    resent = f" resent {th['resent']}" if th.get("resent") is not None else ""
    res = "-" if residual_ms is None else f"{residual_ms:.1f} ms"
    off = "" if offset_ms is None else f" offset {offset_ms:+.0f} ms"
    return (f"{elapsed_s:6.1f}/{duration_s:.0f} s | thermal {th['frames']} ({th['fps']:4.1f} fps) incomplete "
            f"{th['incomplete']} dropped {th['dropped']}{resent} | rgb {rgb['frames']} in {rgb['files']} files "
            f"({rgb['fps']:4.1f} fps) dropped {rgb['dropped']} | markers {markers} | sync residual {res}{off}")


def nuc_pause(prev: Frame | None, f: Frame, period_s: float, tick_hz: float) -> dict | None:
    """The NUC pause before frame f, if any: f follows `prev` with no frame lost between
    (dropped_before 0) yet more than 1.5 frame periods later, by device time (host arrival time
    when a leader was lost). -> nuc event fields (host_ns: last frame before the pause,
    end_host_ns: f, gap_s) or None."""
    if prev is None or f.dropped_before:
        return None
    if prev.timestamp and f.timestamp:
        gap_s = (f.timestamp - prev.timestamp) / tick_hz
    else:
        gap_s = (f.host_ns - prev.host_ns) / 1e9
    if gap_s <= 1.5 * period_s:
        return None
    return {"source": "pause", "host_ns": prev.host_ns, "end_host_ns": f.host_ns, "gap_s": gap_s}


def simulated_parts(camera: str | None, phone_drop: Path | None, syncbox: str | None) -> tuple[str, ...]:
    """Parts of the rig the simulation supplies: all ("thermal", "phone", "syncbox") when no
    device is named; else the thermal camera if it is not named (every session has a thermal
    stream). A simulated phone or lamp beside named devices would record another scene than
    theirs, so those come only with the whole simulated rig."""
    if not (camera or phone_drop or syncbox):
        return ("thermal", "phone", "syncbox")
    return () if camera else ("thermal",)


class Capture:
    def __init__(self, config: CaptureConfig):
        self.cfg = config
        self.sim_parts = simulated_parts(config.camera, config.phone_drop, config.syncbox)
        self.simulated = len(self.sim_parts) == 3          # the whole simulated rig
        self.out = Path(config.out or default_out())
        self.stats = CaptureStats()
        self.frames: queue.Queue[Frame] = queue.Queue()
        self.stop = threading.Event()
        self.threads: list[threading.Thread] = []
        self.camera = None              # FlirA700 when a real camera is used
        self._camera_events_written = 0
        self.sim_camera = None
        self.sim_phone = None
        self.box = None
        self.lamp = None                # simulated sync-box lamp
        self.drop: DropFolder | None = None
        self.t_start = 0.0
        self.t_stop = None              # host s the recording ended
        self._rate: list[tuple[float, int]] = []      # (time, thermal frames) for the fps shown
        # beside the session (same file system, so files are hard-linked in), not inside it
        self.sim_drop_dir = self.out.parent / f".{self.out.name}.sim-phone-drop"

    # -- set-up -----------------------------------------------------------------------------
    def _open_devices(self) -> dict:
        cfg = self.cfg
        meta: dict = {"simulated": self.simulated, "simulated_parts": list(self.sim_parts),
                      "requested_duration_s": cfg.duration_s,
                      "host": platform.node(), "created": dt.datetime.now(dt.timezone.utc).isoformat()}
        if cfg.camera:
            self.camera = flir.FlirA700.open(cfg.camera)
            self.camera.configure(cfg.ir_format)
            cam = self.camera.camera
            meta["thermal"] = {"source": cfg.camera, "tick_hz": cam.tick_hz,
                               "device": asdict(cam.info) if cam.info else None}
        else:
            from rig.simulated import Lamp, SimClock, SimThermalCamera, default_scene
            self.lamp = Lamp() if cfg.sim_lamp and "syncbox" in self.sim_parts else None
            self.scene = default_scene(cfg.seed, lamp=self.lamp, kind=cfg.sim_scene, variant=cfg.sim_variant,
                                       key_hz=cfg.sim_keyframe_hz, render_scale=cfg.sim_render_scale)
            if hasattr(self.scene, "prerender"):
                if cfg.progress:
                    print(f"rendering the simulated world ({self.scene.n_keys} keyframes per camera)...",
                          file=sys.stderr, flush=True)
                kinds = ("thermal", "rgb") if "phone" in self.sim_parts else ("thermal",)
                self.scene.prerender({k: (640, 480) for k in kinds}, until_s=cfg.duration_s + 1)
            now = time.monotonic()
            self.sim_camera = SimThermalCamera(self.scene, ir_format=cfg.ir_format, scene_t0=now,
                                               clock=SimClock(5000.0, 20.0, now), seed=cfg.seed)
            if self.simulated and hasattr(self.scene, "describe"):
                # the simulated rig's "factory calibration": what a real rig gets from `rig calibrate`
                meta["sim_scene"] = self.scene.describe()
            meta["thermal"] = {"source": "simulated", "tick_hz": self.sim_camera.tick_hz,
                               "device": {"model": "simulated FLIR A700"}}
        if cfg.phone_drop:
            self.drop = DropFolder(cfg.phone_drop, settle_s=cfg.settle_s)
            meta["rgb"] = {"source": str(cfg.phone_drop)}
        elif "phone" in self.sim_parts:
            from rig.simulated import SimPhone
            drop = self.sim_drop_dir
            drop.mkdir(parents=True, exist_ok=True)
            now = time.monotonic()
            self.sim_phone = SimPhone(self.scene, drop, segment_s=cfg.sim_segment_s,
                                      clock_offset_s=cfg.sim_phone_offset_s,
                                      drift_ppm=cfg.sim_phone_drift_ppm, scene_t0=self.sim_camera.scene_t0,
                                      clock_t0=now, realtime_minus_monotonic=time.time() - now, seed=cfg.seed)
            self.drop = DropFolder(drop, settle_s=0.2)
            meta["rgb"] = {"source": "simulated phone", "clock_offset_s": cfg.sim_phone_offset_s,
                           "drift_ppm": cfg.sim_phone_drift_ppm}
        if cfg.syncbox:
            from rig.drivers.syncbox import SyncBox
            self.box = SyncBox(cfg.syncbox)
            for _ in range(5):
                self.box.ping()
            meta["syncbox"] = {"port": cfg.syncbox, "identity": self.box.identity}
        return meta

    # -- threads ----------------------------------------------------------------------------
    def _thermal_source(self) -> None:
        try:
            if self.sim_camera is not None:
                self.sim_camera.run(self.frames, self.stop)
                return
            while not self.stop.is_set():
                try:
                    self.frames.put(self.camera.next_frame(timeout=0.2))
                except queue.Empty:
                    continue
        except Exception as exc:                       # surfaces in the progress line and summary
            self.stats.errors.append(f"thermal: {exc}")
            log.exception("thermal source failed")

    def _thermal_writer(self, writer: SessionWriter) -> None:
        prev = None                                    # thumbnail of the last complete frame
        last = None                                    # last frame written
        epoch = -1
        tick_hz = self.camera.camera.tick_hz if self.camera is not None else self.sim_camera.tick_hz
        while not (self.stop.is_set() and self.frames.empty() and not self._source_alive()):
            try:
                batch = [self.frames.get(timeout=0.2)]
            except queue.Empty:
                continue
            while not self.frames.empty() and len(batch) < 64:
                batch.append(self.frames.get_nowait())
            items, pauses = [], []
            for f in batch:
                e = self._epoch_of(f)
                if e != epoch:
                    writer.add_event({"event": "epoch", "epoch": e, **self._epoch_meta(f), "host_ns": f.host_ns})
                    epoch = e
                elif (pause := nuc_pause(last, f, 1 / flir.A700_FPS, tick_hz)) is not None:
                    pauses.append({"event": "nuc", **pause, "frame": writer.n_thermal + len(items)})
                last = f
                counts = f.array()
                th = thumbnail(counts)
                items.append((f.data, {
                    "block_id": f.block_id, "device_ts": f.timestamp, "host_ns": f.host_ns,
                    "host_done_ns": f.host_done_ns, "width": f.width, "height": f.height,
                    "pixel_format": gvsp.PIXEL_FORMAT_NAMES.get(f.pixel_format, hex(f.pixel_format)),
                    "ir_format": f.meta.get("ir_format"), "scale_k": f.meta.get("scale_k"), "epoch": e,
                    "complete": f.complete, "missing_packets": f.missing_packets,
                    "resent_packets": f.resent_packets, "dropped_before": f.dropped_before,
                    "change": change_energy(prev if f.complete else None, th)}))
                prev = th if f.complete else prev
                self.stats.thermal_incomplete += not f.complete
                self.stats.thermal_dropped += f.dropped_before
                self.stats.thermal_resent += f.resent_packets
            writer.add_thermal(items)
            for event in pauses:                       # after the frames they point to are committed
                writer.add_event(event)
            self.stats.thermal_frames += len(items)

    def _source_alive(self) -> bool:
        return any(t.name == "thermal-source" and t.is_alive() for t in self.threads)

    def _epoch_of(self, f: Frame) -> int:
        return self.camera._epoch_index if self.camera is not None else 0

    def _epoch_meta(self, f: Frame) -> dict:
        if self.camera is not None:
            return self.camera.epochs[self.camera._epoch_index].meta()
        return {"ir_format": f.meta.get("ir_format"), "scale_k": f.meta.get("scale_k")}

    def _phone(self, writer: SessionWriter) -> None:
        deadline = None
        while True:
            if deadline is None and self.stop.is_set() and not self._sim_phone_alive():
                # files still arriving get their settle time (and a little more), then we stop
                deadline = time.monotonic() + 2 * self.drop.settle_s + 2.0
            for path in self.drop.poll():
                self._ingest(writer, path)
            if deadline is not None and (time.monotonic() > deadline or not self.drop.pending()):
                return
            time.sleep(0.1 if self.stop.is_set() else 0.25)

    def _sim_phone_alive(self) -> bool:
        return any(t.name == "sim-phone" and t.is_alive() for t in self.threads)

    def _ingest(self, writer: SessionWriter, path: Path) -> None:
        arrived = time.monotonic_ns()
        try:
            if path.suffix.lower() in PHOTO_SUFFIXES:
                writer.add_rgb_file(path, [], {"kind": "photo", "host_ns": arrived})
            else:
                info = probe_video(path)
                frames = [{"frame": f["frame"], "pts": f["pts"], "pts_s": f["pts_s"], "motion": f["motion"]}
                          for f in info.frames]
                record = {"kind": "video", "host_ns": arrived, **info.file_record()}
                if self.sim_phone is not None:    # simulated rig: the file's truth, for grading live
                    record["sim_truth"] = next((t for t in self.sim_phone.truth if t["file"] == path.name), None)
                writer.add_rgb_file(path, frames, record)
                pts = [f["pts_s"] for f in frames]
                self.stats.rgb_frames += len(frames)
                self.stats.rgb_files += 1
                self.stats.rgb_dropped += pts_drops(pts)
                self.stats.rgb_span_s += max(pts) - min(pts) if len(pts) > 1 else 0.0
        except Exception as exc:          # a broken file must not stop the capture
            self.stats.errors.append(f"{path.name}: {exc}")
            writer.add_event({"event": "rgb_error", "file": str(path), "error": str(exc), "host_ns": arrived})
        self.drop.mark_done(path)

    def _sim_syncbox(self, writer: SessionWriter) -> None:
        """The simulated rig's sync box: pulses the lamp, reports switches on the host clock."""
        n = 0
        rng = np.random.default_rng(self.cfg.seed)
        # irregular intervals (like the box's): a periodic train would fit at any whole period
        while not self.stop.wait(self.cfg.marker_period_s * rng.uniform(0.6, 1.4) - self.cfg.marker_on_s):
            for state in (1, 0):
                t = time.monotonic()
                self.lamp.switch(state, t - self.sim_camera.scene_t0)     # the scene's time
                n += 1
                writer.add_event({"event": "marker", "n": n, "state": state, "host_ns": int(t * 1e9),
                                  "host_s": t, "simulated": True})
                self.stats.markers += 1
                if state and self.stop.wait(self.cfg.marker_on_s):
                    break

    def _camera_events(self, writer: SessionWriter) -> None:
        """Persist what the camera profile logged since the last call (commanded NUCs, IRFormat
        changes)."""
        if self.camera is not None:
            new = self.camera.events[self._camera_events_written:]
            self._camera_events_written += len(new)
            for event in new:
                writer.add_event(event)

    def _poll_syncbox(self, writer: SessionWriter) -> None:
        self.box.ping()
        rate, offset = self.box.clock()
        while not self.box.markers.empty():
            m = self.box.markers.get_nowait()
            writer.add_event({"event": "marker", "n": m.n, "state": m.state, "box_us": m.box_us,
                              "host_ns": m.host_ns, "host_s": rate * m.box_us / 1e6 + offset})
            self.stats.markers += 1

    # -- run --------------------------------------------------------------------------------
    def run(self) -> dict:
        cfg = self.cfg
        if self.out.exists() and any(self.out.iterdir()):
            raise FileExistsError(f"session folder {self.out} exists and is not empty")
        meta = self._open_devices()
        writer = SessionWriter(self.out, meta)
        reader = None
        last_sync = None
        try:
            if self.camera is not None:
                self.camera.start(StreamConfig(packet_size=cfg.packet_size))
            if self.box is not None:
                self.box.start(cfg.marker_period_s, cfg.marker_on_s)
            self._spawn("thermal-source", self._thermal_source)
            self._spawn("thermal-writer", self._thermal_writer, writer)
            if self.drop is not None:
                self._spawn("phone", self._phone, writer)
            if self.sim_phone is not None:
                self._spawn("sim-phone", self.sim_phone.run, self.stop)
            if self.lamp is not None:
                self._spawn("sim-syncbox", self._sim_syncbox, writer)
            self.t_start = time.monotonic()
            next_sync = self.t_start + cfg.sync_every_s
            try:
                while (elapsed := time.monotonic() - self.t_start) < cfg.duration_s:
                    time.sleep(0.5)
                    self._camera_events(writer)
                    if self.box is not None:
                        self._poll_syncbox(writer)
                    if time.monotonic() >= next_sync:
                        reader = reader or open_session(self.out)
                        reader.refresh()
                        last_sync = synchronise_session(reader)
                        writer.write_sync(last_sync.as_dict())
                        next_sync += cfg.sync_every_s
                    if cfg.progress:
                        self._progress(elapsed, last_sync)
            except KeyboardInterrupt:
                print("\ninterrupted: finishing the session", file=sys.stderr)
        finally:
            self.t_stop = time.monotonic()
            if self.sim_phone is not None:
                self.sim_phone.stopped_at = self.t_stop
            self.stop.set()
            self._shutdown(writer)
        reader = open_session(self.out)
        final = synchronise_session(reader)
        writer.write_sync(final.as_dict())
        summary = {"stats": asdict(self.stats), "sync_residual_ms": final.residual_ms,
                   "simulated": self.simulated}
        if self.sim_phone is not None:
            summary["sim_truth"] = self.sim_phone.truth
            shutil.rmtree(self.sim_drop_dir, ignore_errors=True)
        writer.close(summary)
        if cfg.progress:
            # the recording's real rates (device clock, PTS), not the last seconds' arrivals
            streams = session_info(reader)["streams"]
            streams["thermal"]["resent"] = self.stats.thermal_resent
            line = progress_line(self.t_stop - self.t_start, cfg.duration_s, streams, self.stats.markers,
                                 final.residual_ms, final.rgb_offset_ms)
            print(f"\r{line}   ", file=sys.stderr, flush=True)
        return summary

    def _spawn(self, name: str, target, *args) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        t.start()
        self.threads.append(t)

    def _shutdown(self, writer: SessionWriter) -> None:
        if self.camera is not None:
            try:
                self.camera.camera.stop_acquisition()
            except Exception as exc:
                self.stats.errors.append(f"stopping camera: {exc}")
        for t in self.threads:
            t.join(timeout=120)
        self._camera_events(writer)
        if self.box is not None:
            self._poll_syncbox(writer)
            rate, offset = self.box.clock()
            writer.add_event({"event": "syncbox_clock", "rate": rate, "offset": offset})
            self.box.close()
        if self.camera is not None:
            if self.camera.camera.stream is not None:
                self.stats.gige_stream = self.camera.camera.stream.stats.as_dict()
            self.camera.close()

    def _progress(self, elapsed: float, sync) -> None:
        st = self.stats
        now = time.monotonic()
        self._rate.append((now, st.thermal_frames))
        while len(self._rate) > 2 and now - self._rate[0][0] > 2.0:
            self._rate.pop(0)
        (t0, n0), (t1, n1) = self._rate[0], self._rate[-1]
        streams = {"thermal": {"frames": st.thermal_frames, "fps": (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0,
                               "incomplete": st.thermal_incomplete, "dropped": st.thermal_dropped,
                               "resent": st.thermal_resent},
                   "rgb": {"frames": st.rgb_frames, "files": st.rgb_files, "dropped": st.rgb_dropped,
                           # phone files arrive whole, after the fact: their recorded rate
                           "fps": (st.rgb_frames - st.rgb_files) / st.rgb_span_s if st.rgb_span_s else 0.0}}
        line = progress_line(elapsed, self.cfg.duration_s, streams, st.markers,
                             sync.residual_ms if sync is not None else None,
                             sync.rgb_offset_ms if sync is not None else None)
        print(f"\r{line}   ", end="", file=sys.stderr, flush=True)


def register(sub) -> None:
    p = sub.add_parser(
        "capture", help="record a session (simulated rig when no device is named)",
        description="Record thermal frames, phone videos and sync-box markers into a crash-safe\n"
                    "session folder (see docs/rig.md, 'Session folder').\n"
                    "With no --camera, --phone-drop or --syncbox the simulated rig is captured (thermal\n"
                    "camera, phone and sync-box lamp). With --phone-drop and/or --syncbox but no --camera,\n"
                    "those devices are recorded beside the simulated thermal camera (no simulated phone\n"
                    "or lamp then: they would show another scene than the real devices).",
        formatter_class=HelpFormatter,
        epilog="examples:\n  rig capture --duration 10 --out /tmp/s1            # simulated rig\n"
               "  rig capture --phone-drop ~/Drop --duration 30      # real phone, simulated thermal camera\n"
               "  rig capture --camera gige://192.168.1.20 --phone-drop ~/Drop --syncbox /dev/ttyACM0\n"
               "  rig info /tmp/s1 --json")
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds to record")
    p.add_argument("--camera", help="thermal camera, gige://HOST[:PORT] (not named: simulated)")
    p.add_argument("--phone-drop", type=Path, help="folder where the phone's files arrive")
    p.add_argument("--syncbox", help="serial port of the sync box, e.g. /dev/ttyACM0")
    p.add_argument("--out", type=Path, help="session folder to create (default sessions/<date-time>)")
    p.add_argument("--ir-format", default="TemperatureLinear10mK", choices=flir.IR_FORMATS)
    p.add_argument("--packet-size", type=int, default=1500, help="GVSP packet size (SCPS), bytes")
    p.add_argument("--settle", type=float, default=1.0, help="seconds a dropped file must stay unchanged")
    p.add_argument("--seed", type=int, default=0, help="simulated rig: scene seed")
    p.add_argument("--sim-scene", choices=["world", "calibration", "synthetic"], default="world",
                   help="simulated rig: the project's simulated world, its heated checkerboard (for "
                        "rig calibrate), or cheap synthetic warm blobs")
    p.add_argument("--sim-variant", default="default", choices=VARIANTS, help="simulated world: variant")
    p.add_argument("--sim-keyframes", type=float, default=5.0, metavar="HZ",
                   help="simulated world: keyframes per second (blended between; 30 for sharp moving views)")
    p.add_argument("--sim-render-scale", type=float, default=0.2, metavar="S",
                   help="simulated world: keyframes rendered at S x 640x480 and upscaled")
    p.add_argument("--no-sim-lamp", action="store_true",
                   help="simulated rig without its sync-box lamp: sync falls back to cross-correlation")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    add_serve_arguments(p)
    p.set_defaults(func=main)


def main(args) -> int:
    if args.duration <= 0:
        print("rig capture: --duration must be positive", file=sys.stderr)
        return 2
    cfg = CaptureConfig(duration_s=args.duration, out=args.out, camera=args.camera,
                        phone_drop=args.phone_drop, syncbox=args.syncbox, ir_format=args.ir_format,
                        packet_size=args.packet_size, settle_s=args.settle, seed=args.seed,
                        sim_lamp=not args.no_sim_lamp, sim_scene=args.sim_scene, sim_variant=args.sim_variant,
                        sim_keyframe_hz=args.sim_keyframes, sim_render_scale=args.sim_render_scale,
                        progress=not args.quiet)
    handle = None
    try:
        cap = Capture(cfg)
        handle = serve_from_args(args, session_dir=cap.out)
        summary = cap.run()
    except (FileExistsError, NotADirectoryError, ValueError, OSError, SyncBoxError, GvcpError,
            GenicamXmlError) as exc:
        print(f"rig capture: {exc}", file=sys.stderr)
        return 2
    finally:
        if handle:
            handle.stop()
    print(cap.out)
    return 1 if summary["stats"]["errors"] else 0
