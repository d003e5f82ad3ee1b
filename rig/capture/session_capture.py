"""`Capture`: open the devices, run their streams into a session for the duration, finish the
session (final sync, summary). Every frame committed before a crash stays readable."""
from __future__ import annotations

import queue
import shutil
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

from rig.capture import streams
from rig.capture.config import CaptureConfig, CaptureStats, default_out
from rig.capture.devices import Devices, close_devices, open_devices, stop_camera
from rig.capture.progress import LiveStreams, progress_line
from rig.drivers.gige.stream import Frame, StreamConfig
from rig.info import session_info
from rig.session import SessionWriter, open_session
from rig.sync import synchronise_session


class Capture:
    def __init__(self, config: CaptureConfig):
        self.cfg = config
        self.out = Path(config.out or default_out())
        self.stats = CaptureStats()
        self.frames: queue.Queue[Frame] = queue.Queue()
        self.stop = threading.Event()
        self.threads: list[threading.Thread] = []
        self.dev: Devices | None = None
        self.t_start = 0.0
        self.t_stop = None              # host s the recording ended

    def run(self) -> dict:
        cfg = self.cfg
        if self.out.exists() and any(self.out.iterdir()):
            raise FileExistsError(f"session folder {self.out} exists and is not empty")
        dev = self.dev = open_devices(cfg, self.out)
        writer = SessionWriter(self.out, dev.meta)
        try:
            self._record(dev, writer)
        finally:
            self.t_stop = time.monotonic()
            if dev.sim_phone is not None:
                dev.sim_phone.stopped_at = self.t_stop
            self.stop.set()
            self._shutdown(dev, writer)
        return self._finish(dev, writer)

    def _record(self, dev: Devices, writer: SessionWriter) -> None:
        """Start every stream; until the duration is over, move markers and camera events in,
        re-estimate sync every sync_every_s and print the status line."""
        cfg, st = self.cfg, self.stats
        if dev.camera is not None:
            dev.camera.start(StreamConfig(packet_size=cfg.packet_size))
        if dev.box is not None:
            dev.box.start(cfg.marker_period_s, cfg.marker_on_s)
        self._spawn("thermal-source", streams.thermal_source, dev, self.frames, self.stop, st)
        self._spawn("thermal-writer", streams.thermal_writer, dev, writer, self.frames, self.stop, st,
                    lambda: self._alive("thermal-source"))
        if dev.drop is not None:
            self._spawn("phone", streams.phone_files, dev, writer, self.stop, st, lambda: self._alive("sim-phone"))
        if dev.sim_phone is not None:
            self._spawn("sim-phone", dev.sim_phone.run, self.stop)
        if dev.lamp is not None:
            self._spawn("sim-syncbox", streams.sim_syncbox, dev, writer, self.stop, st, cfg)
        self.t_start = time.monotonic()
        next_sync = self.t_start + cfg.sync_every_s
        reader, last_sync, live = None, None, LiveStreams()
        try:
            while (elapsed := time.monotonic() - self.t_start) < cfg.duration_s:
                time.sleep(0.5)
                streams.write_camera_events(dev, writer)
                if dev.box is not None:
                    streams.poll_syncbox(dev, writer, st)
                if time.monotonic() >= next_sync:
                    reader = reader or open_session(self.out)
                    reader.refresh()
                    last_sync = synchronise_session(reader)
                    writer.write_sync(last_sync.as_dict())
                    next_sync += cfg.sync_every_s
                if cfg.progress:
                    line = progress_line(elapsed, cfg.duration_s, live(st), st.markers,
                                         last_sync.residual_ms if last_sync is not None else None,
                                         last_sync.rgb_offset_ms if last_sync is not None else None)
                    print(f"\r{line}   ", end="", file=sys.stderr, flush=True)
        except KeyboardInterrupt:
            print("\ninterrupted: finishing the session", file=sys.stderr)

    def _finish(self, dev: Devices, writer: SessionWriter) -> dict:
        """The final sync over the whole session, the summary, the closing status line."""
        reader = open_session(self.out)
        final = synchronise_session(reader)
        writer.write_sync(final.as_dict())
        summary = {"stats": asdict(self.stats), "sync_residual_ms": final.residual_ms,
                   "simulated": dev.simulated}
        if dev.sim_phone is not None:
            summary["sim_truth"] = dev.sim_phone.truth
            shutil.rmtree(dev.sim_drop_dir, ignore_errors=True)
        writer.close(summary)
        if self.cfg.progress:
            # the recording's real rates (device clock, PTS), not the last seconds' arrivals
            info = session_info(reader)["streams"]
            info["thermal"]["resent"] = self.stats.thermal_resent
            line = progress_line(self.t_stop - self.t_start, self.cfg.duration_s, info, self.stats.markers,
                                 final.residual_ms, final.rgb_offset_ms)
            print(f"\r{line}   ", file=sys.stderr, flush=True)
        return summary

    def _spawn(self, name: str, target, *args) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        t.start()
        self.threads.append(t)

    def _alive(self, name: str) -> bool:
        return any(t.name == name and t.is_alive() for t in self.threads)

    def _shutdown(self, dev: Devices, writer: SessionWriter) -> None:
        stop_camera(dev, self.stats)
        for t in self.threads:
            t.join(timeout=120)
        streams.write_camera_events(dev, writer)
        if dev.box is not None:
            streams.poll_syncbox(dev, writer, self.stats)
            rate, offset = dev.box.clock()
            writer.add_event({"event": "syncbox_clock", "rate": rate, "offset": offset})
        close_devices(dev, self.stats)
