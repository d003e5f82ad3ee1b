"""The devices of a capture, real or simulated: opened from a CaptureConfig, and what the rest of
the capture asks of them (the thermal clock, IRFormat epochs, camera events), then closed."""
from __future__ import annotations

import datetime as dt
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from rig.capture.config import CaptureConfig, CaptureStats, simulated_parts
from rig.drivers import flir
from rig.drivers.gige.stream import Frame
from rig.drivers.phone import DropFolder
from rig.drivers.profiles import open_thermal_camera


@dataclass
class Devices:
    sim_parts: tuple[str, ...]
    sim_drop_dir: Path                   # the simulated phone's drop folder
    camera: object = None                # a ThermalCamera profile when a real camera is used
    sim_camera: object = None
    scene: object = None                 # the simulated world
    sim_phone: object = None
    box: object = None                   # SyncBox
    lamp: object = None                  # simulated sync-box lamp
    drop: DropFolder | None = None
    meta: dict = field(default_factory=dict)   # for session.json
    events_written: int = 0              # camera events already in the session

    @property
    def simulated(self) -> bool:
        """The whole rig is simulated."""
        return len(self.sim_parts) == 3

    @property
    def frame_period_s(self) -> float:
        rate = self.camera.frame_rate if self.camera is not None else None
        return 1.0 / (rate or flir.A700_FPS)

    @property
    def tick_hz(self) -> float:
        return self.camera.camera.tick_hz if self.camera is not None else self.sim_camera.tick_hz

    def epoch_of(self, f: Frame) -> int:
        """Which IRFormat epoch (scale change) frame f belongs to."""
        return self.camera._epoch_index if self.camera is not None else 0

    def epoch_meta(self, f: Frame) -> dict:
        if self.camera is not None:
            return self.camera.epochs[self.camera._epoch_index].meta()
        return {"ir_format": f.meta.get("ir_format"), "scale_k": f.meta.get("scale_k"), "radiometric": True}

    def new_camera_events(self) -> list[dict]:
        """What the camera profile logged since the last call (commanded NUCs, IRFormat changes)."""
        if self.camera is None:
            return []
        new = self.camera.events[self.events_written:]
        self.events_written += len(new)
        return new


def sim_drop_dir(out: Path) -> Path:
    """Beside the session (same file system, so files are hard-linked in), not inside it."""
    return out.parent / f".{out.name}.sim-phone-drop"


def open_devices(cfg: CaptureConfig, out: Path) -> Devices:
    """Open the named devices and simulate the rest (config.simulated_parts)."""
    dev = Devices(simulated_parts(cfg.camera, cfg.phone_drop, cfg.syncbox), sim_drop_dir(out))
    meta = dev.meta
    meta.update({"simulated": dev.simulated, "simulated_parts": list(dev.sim_parts),
                 "requested_duration_s": cfg.duration_s,
                 "host": platform.node(), "created": dt.datetime.now(dt.timezone.utc).isoformat()})
    if cfg.camera:
        dev.camera = open_thermal_camera(cfg.camera, cfg.profile, cfg.ir_format, cfg.kelvin_map, cfg.frame_rate)
        cam = dev.camera.camera
        try:
            if cfg.packet_size == 0:        # now, so session.json says what the stream will use
                cam.negotiate_packet_size()
            ptp = dev.camera.enable_ptp() if cfg.ptp else {"enabled": False, "why": "--no-ptp"}
        except Exception:
            dev.camera.close()
            raise
        kmap = getattr(dev.camera, "kelvin_map", None)
        meta["thermal"] = {"source": cfg.camera, "tick_hz": cam.tick_hz,
                           "device": asdict(cam.info) if cam.info else None,
                           "profile": dev.camera.profile, "radiometric": dev.camera.profile != "generic",
                           "kelvin_map": kmap.as_dict() if kmap else None, "frame_rate": dev.camera.frame_rate,
                           "packet_size": cfg.packet_size or cam.packet_size.size,
                           "packet_size_tested": bool(cam.packet_size and cam.packet_size.tested), "ptp": ptp}
    else:
        from rig.simulated import Lamp, SimClock, SimThermalCamera, default_scene
        dev.lamp = Lamp() if cfg.sim_lamp and "syncbox" in dev.sim_parts else None
        dev.scene = default_scene(cfg.seed, lamp=dev.lamp, kind=cfg.sim_scene, variant=cfg.sim_variant,
                                  key_hz=cfg.sim_keyframe_hz, render_scale=cfg.sim_render_scale)
        if hasattr(dev.scene, "prerender"):
            if cfg.progress:
                print(f"rendering the simulated world ({dev.scene.n_keys} keyframes per camera)...",
                      file=sys.stderr, flush=True)
            kinds = ("thermal", "rgb") if "phone" in dev.sim_parts else ("thermal",)
            dev.scene.prerender({k: (640, 480) for k in kinds}, until_s=cfg.duration_s + 1)
        now = time.monotonic()
        dev.sim_camera = SimThermalCamera(dev.scene, ir_format=cfg.ir_format, scene_t0=now,
                                          clock=SimClock(5000.0, 20.0, now), seed=cfg.seed)
        if dev.simulated and hasattr(dev.scene, "describe"):
            # the simulated rig's "factory calibration": what a real rig gets from `rig calibrate`
            meta["sim_scene"] = dev.scene.describe()
        meta["thermal"] = {"source": "simulated", "tick_hz": dev.sim_camera.tick_hz,
                           "device": {"model": "simulated FLIR A700"}, "profile": "flir-irformat",
                           "radiometric": True}
    if cfg.phone_drop:
        dev.drop = DropFolder(cfg.phone_drop, settle_s=cfg.settle_s)
        meta["rgb"] = {"source": str(cfg.phone_drop)}
    elif "phone" in dev.sim_parts:
        from rig.simulated import SimPhone
        dev.sim_drop_dir.mkdir(parents=True, exist_ok=True)
        now = time.monotonic()
        dev.sim_phone = SimPhone(dev.scene, dev.sim_drop_dir, segment_s=cfg.sim_segment_s,
                                 clock_offset_s=cfg.sim_phone_offset_s,
                                 drift_ppm=cfg.sim_phone_drift_ppm, scene_t0=dev.sim_camera.scene_t0,
                                 clock_t0=now, realtime_minus_monotonic=time.time() - now, seed=cfg.seed)
        dev.drop = DropFolder(dev.sim_drop_dir, settle_s=0.2)
        meta["rgb"] = {"source": "simulated phone", "clock_offset_s": cfg.sim_phone_offset_s,
                       "drift_ppm": cfg.sim_phone_drift_ppm}
    if cfg.syncbox:
        from rig.drivers.syncbox import SyncBox
        dev.box = SyncBox(cfg.syncbox)
        for _ in range(5):
            dev.box.ping()
        meta["syncbox"] = {"port": cfg.syncbox, "identity": dev.box.identity}
    return dev


def stop_camera(dev: Devices, stats: CaptureStats) -> None:
    if dev.camera is not None:
        try:
            dev.camera.camera.stop_acquisition()
        except Exception as exc:
            stats.errors.append(f"stopping camera: {exc}")


def close_devices(dev: Devices, stats: CaptureStats) -> None:
    """After the threads ended: the sync box and the camera (its receiver's counters kept)."""
    if dev.box is not None:
        dev.box.close()
    if dev.camera is not None:
        if dev.camera.camera.stream is not None:
            stats.gige_stream = dev.camera.camera.stream.stats.as_dict()
        dev.camera.close()
