"""The capture's data paths, each run in its own thread: the thermal source fills a queue; the
thermal writer commits frames to the session in group commits; the phone thread takes finished
files from the drop folder, decodes their PTS and motion energy, and links them in; the
simulated sync box pulses the lamp. Markers and camera events are moved in from the main thread."""
from __future__ import annotations

import logging
import queue
import threading
import time
from pathlib import Path

import numpy as np

from rig.capture.config import CaptureConfig, CaptureStats
from rig.capture.devices import Devices
from rig.drivers.gige import gvsp
from rig.drivers.gige.stream import Frame
from rig.drivers.phone import PHOTO_SUFFIXES, probe_video, pts_drops
from rig.session import SessionWriter
from rig.sync import change_energy, thumbnail

log = logging.getLogger(__name__)


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


def thermal_source(dev: Devices, frames: queue.Queue, stop: threading.Event, stats: CaptureStats) -> None:
    """Frames from the camera (or the simulated one) into `frames` until `stop`."""
    try:
        if dev.sim_camera is not None:
            dev.sim_camera.run(frames, stop)
            return
        while not stop.is_set():
            try:
                frames.put(dev.camera.next_frame(timeout=0.2))
            except queue.Empty:
                continue
    except Exception as exc:                       # surfaces in the progress line and summary
        stats.errors.append(f"thermal: {exc}")
        log.exception("thermal source failed")


def thermal_writer(dev: Devices, writer: SessionWriter, frames: queue.Queue, stop: threading.Event,
                   stats: CaptureStats, source_alive) -> None:
    """Commit queued frames (up to 64 at a time) with their metadata, IRFormat epochs and NUC
    pauses, until stopped, the queue is empty and source_alive() is False."""
    prev = None                                    # thumbnail of the last complete frame
    last = None                                    # last frame written
    epoch = -1
    tick_hz = dev.tick_hz
    while not (stop.is_set() and frames.empty() and not source_alive()):
        try:
            batch = [frames.get(timeout=0.2)]
        except queue.Empty:
            continue
        while not frames.empty() and len(batch) < 64:
            batch.append(frames.get_nowait())
        items, pauses = [], []
        for f in batch:
            e = dev.epoch_of(f)
            if e != epoch:
                writer.add_event({"event": "epoch", "epoch": e, **dev.epoch_meta(f), "host_ns": f.host_ns})
                epoch = e
            elif (pause := nuc_pause(last, f, dev.frame_period_s, tick_hz)) is not None:
                pauses.append({"event": "nuc", **pause, "frame": writer.n_thermal + len(items)})
            last = f
            counts = f.array()
            th = thumbnail(counts)
            items.append((f.data, {
                "block_id": f.block_id, "device_ts": f.timestamp, "host_ns": f.host_ns,
                "host_done_ns": f.host_done_ns, "width": f.width, "height": f.height,
                "pixel_format": gvsp.PIXEL_FORMAT_NAMES.get(f.pixel_format, hex(f.pixel_format)),
                "ir_format": f.meta.get("ir_format"), "scale_k": f.meta.get("scale_k"), "epoch": e,
                **({"offset_k": f.meta["offset_k"]} if f.meta.get("offset_k") else {}),
                "complete": f.complete, "missing_packets": f.missing_packets,
                "resent_packets": f.resent_packets, "dropped_before": f.dropped_before,
                "change": change_energy(prev if f.complete else None, th)}))
            prev = th if f.complete else prev
            stats.thermal_incomplete += not f.complete
            stats.thermal_dropped += f.dropped_before
            stats.thermal_resent += f.resent_packets
        writer.add_thermal(items)
        for event in pauses:                       # after the frames they point to are committed
            writer.add_event(event)
        stats.thermal_frames += len(items)


def phone_files(dev: Devices, writer: SessionWriter, stop: threading.Event, stats: CaptureStats,
                sim_phone_alive) -> None:
    """Link finished drop-folder files into the session until stopped; files still arriving then
    get their settle time (and a little more)."""
    deadline = None
    while True:
        if deadline is None and stop.is_set() and not sim_phone_alive():
            deadline = time.monotonic() + 2 * dev.drop.settle_s + 2.0
        for path in dev.drop.poll():
            ingest(dev, writer, path, stats)
        if deadline is not None and (time.monotonic() > deadline or not dev.drop.pending()):
            return
        time.sleep(0.1 if stop.is_set() else 0.25)


def ingest(dev: Devices, writer: SessionWriter, path: Path, stats: CaptureStats) -> None:
    """One phone file into the session; a broken file is an error event, never the end of the capture."""
    arrived = time.monotonic_ns()
    try:
        if path.suffix.lower() in PHOTO_SUFFIXES:
            writer.add_rgb_file(path, [], {"kind": "photo", "host_ns": arrived})
        else:
            info = probe_video(path)
            frames = [{"frame": f["frame"], "pts": f["pts"], "pts_s": f["pts_s"], "motion": f["motion"]}
                      for f in info.frames]
            record = {"kind": "video", "host_ns": arrived, **info.file_record()}
            if dev.sim_phone is not None:    # simulated rig: the file's truth, for grading live
                record["sim_truth"] = next((t for t in dev.sim_phone.truth if t["file"] == path.name), None)
            writer.add_rgb_file(path, frames, record)
            pts = [f["pts_s"] for f in frames]
            stats.rgb_frames += len(frames)
            stats.rgb_files += 1
            stats.rgb_dropped += pts_drops(pts)
            stats.rgb_span_s += max(pts) - min(pts) if len(pts) > 1 else 0.0
    except Exception as exc:
        stats.errors.append(f"{path.name}: {exc}")
        writer.add_event({"event": "rgb_error", "file": str(path), "error": str(exc), "host_ns": arrived})
    dev.drop.mark_done(path)


def sim_syncbox(dev: Devices, writer: SessionWriter, stop: threading.Event, stats: CaptureStats,
                cfg: CaptureConfig) -> None:
    """The simulated rig's sync box: pulses the lamp, reports switches on the host clock."""
    n = 0
    rng = np.random.default_rng(cfg.seed)
    # irregular intervals (like the box's): a periodic train would fit at any whole period
    while not stop.wait(cfg.marker_period_s * rng.uniform(0.6, 1.4) - cfg.marker_on_s):
        for state in (1, 0):
            t = time.monotonic()
            dev.lamp.switch(state, t - dev.sim_camera.scene_t0)     # the scene's time
            n += 1
            writer.add_event({"event": "marker", "n": n, "state": state, "host_ns": int(t * 1e9),
                              "host_s": t, "simulated": True})
            stats.markers += 1
            if state and stop.wait(cfg.marker_on_s):
                break


def poll_syncbox(dev: Devices, writer: SessionWriter, stats: CaptureStats) -> None:
    """Ping the sync box (its clock model) and move its markers into the session."""
    dev.box.ping()
    rate, offset = dev.box.clock()
    while not dev.box.markers.empty():
        m = dev.box.markers.get_nowait()
        writer.add_event({"event": "marker", "n": m.n, "state": m.state, "box_us": m.box_us,
                          "host_ns": m.host_ns, "host_s": rate * m.box_us / 1e6 + offset})
        stats.markers += 1


def write_camera_events(dev: Devices, writer: SessionWriter) -> None:
    for event in dev.new_camera_events():
        writer.add_event(event)
