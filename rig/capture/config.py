"""What `rig capture` records and how (CaptureConfig), and what it counted (CaptureStats)."""
from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class CaptureConfig:
    duration_s: float = 60.0
    out: Path | None = None                 # default: sessions/YYYYmmdd-HHMMSS
    camera: str | None = None               # gige://HOST[:PORT]
    phone_drop: Path | None = None
    syncbox: str | None = None              # serial port
    ir_format: str = "TemperatureLinear10mK"
    profile: str = "auto"                   # camera profile (rig/drivers/profiles.py)
    kelvin_map: object = None               # generic profile: KelvinMap from --kelvin-map
    frame_rate: float | None = None         # thermal frame rate (None: FLIR 30 Hz, else the camera's)
    ptp: bool = True                        # enable IEEE 1588 on the camera where it offers it
    packet_size: int = 0                    # GVSP packet size; 0: negotiated with test packets
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


def simulated_parts(camera: str | None, phone_drop: Path | None, syncbox: str | None) -> tuple[str, ...]:
    """Parts of the rig the simulation supplies: all ("thermal", "phone", "syncbox") when no
    device is named; else the thermal camera if it is not named (every session has a thermal
    stream). A simulated phone or lamp beside named devices would record another scene than
    theirs, so those come only with the whole simulated rig."""
    if not (camera or phone_drop or syncbox):
        return ("thermal", "phone", "syncbox")
    return () if camera else ("thermal",)
