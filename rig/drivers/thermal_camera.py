"""What every thermal camera profile shares (FLIR families in rig/drivers/flir.py, any other GigE
Vision camera in rig/drivers/generic_gige.py): a `GigECamera` underneath, acquisition epochs
(what a count meant from one AcquisitionStart on), frames tagged with their epoch, events.

A profile's `configure()` sets the camera up (refusing with `UnsupportedCamera`, one line naming
the camera, the missing feature and what to do); `start()` opens an epoch; `next_frame()` returns
frames whose `meta` says how to read them: ir_format, scale_k and offset_k (kelvin = counts x
scale_k + offset_k; scale_k None: not temperatures), radiometric, object parameters and
calibration (FLIR's Radiometric format)."""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

from rig.drivers.gige.camera import GigECamera
from rig.drivers.gige.stream import Frame, GvspStream, StreamConfig


class UnsupportedCamera(ValueError):
    """The device lacks a feature this profile needs; the message names the camera and the feature."""


@dataclass
class Epoch:
    """What was in force from one AcquisitionStart on."""
    start_ticks: int
    ir_format: str                       # FLIR's IRFormat name, or "Counts" (not temperatures)
    scale_k: float | None                # kelvin per count (None: counts only)
    offset_k: float = 0.0                # kelvin at count 0
    radiometric: bool = True             # the camera measures temperature (not a user-given map)
    params: object = None                # flir.ObjectParameters (FLIR formats)
    calibration: object = None           # flir.RadiometricCalibration (FLIR Radiometric)

    def meta(self) -> dict:
        return {"ir_format": self.ir_format, "scale_k": self.scale_k, "offset_k": self.offset_k,
                "radiometric": self.radiometric,
                "object_parameters": asdict(self.params) if self.params else None,
                "calibration": asdict(self.calibration) if self.calibration else None}


@dataclass
class ThermalCamera:
    """A profile on top of a `GigECamera`. Subclasses implement configure() and new_epoch()."""
    camera: GigECamera
    epochs: list[Epoch] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)     # NUCs and format changes, host time
    frame_rate: float | None = None                     # what configure() set or read (Hz)
    _epoch_index: int = 0

    profile = "abstract"

    @classmethod
    def open(cls, url: str, **kw) -> "ThermalCamera":
        return cls(GigECamera.open(url, **kw))

    @property
    def features(self):
        return self.camera.features

    @property
    def name(self) -> str:
        info = self.camera.info
        return f"{info.manufacturer} {info.model}".strip() if info else "the camera"

    def missing(self, names, what: str) -> None:
        """Refuse in one line if any feature of `names` is missing."""
        lacking = [n for n in names if not self.features.has(n)]
        if lacking:
            raise UnsupportedCamera(f"{self.name} has no GenICam feature {', '.join(lacking)}: {what}")

    def configure(self, **kw) -> None:
        raise NotImplementedError

    def new_epoch(self, start_ticks: int) -> Epoch:
        raise NotImplementedError

    def start(self, config: StreamConfig | None = None) -> GvspStream:
        """AcquisitionStart, opening a new epoch at the latched device time."""
        start_ticks, _ = self.camera.device.latch_timestamp()
        self.epochs.append(self.new_epoch(start_ticks))
        return self.camera.start_stream(config)

    def tag(self, frame: Frame) -> Frame:
        """Attach the epoch in force when the frame was produced."""
        if frame.has_leader:
            while (self._epoch_index + 1 < len(self.epochs)
                   and frame.timestamp >= self.epochs[self._epoch_index + 1].start_ticks):
                self._epoch_index += 1
        frame.meta.update(self.epochs[self._epoch_index].meta())
        return frame

    def next_frame(self, timeout: float | None = None) -> Frame:
        return self.tag(self.camera.stream.get(timeout=timeout))

    def enable_ptp(self, wait_s: float = 5.0, poll_s: float = 0.1) -> dict:
        """IEEE 1588 (PTP) where the camera offers it: SFNC `PtpEnable` (GigE Vision 1.2:
        `GevIEEE1588`) set, then `PtpStatus` (`GevIEEE1588Status`) read until the port settles
        (Slave: its clock follows the network's grandmaster, so frame timestamps run at the
        grandmaster's rate; Master: no other clock answered, the camera's own crystal rules).
        -> {"enabled", "status", "feature"} or {"enabled": False, "why"} for session.json."""
        f = self.features
        names = next(((en, st) for en, st in (("PtpEnable", "PtpStatus"), ("GevIEEE1588", "GevIEEE1588Status"))
                      if f.has(en)), None)
        if names is None:
            return {"enabled": False, "why": "the camera has no PtpEnable or GevIEEE1588 feature"}
        enable, status = names
        f.set(enable, True)
        deadline, state = time.monotonic() + wait_s, None
        while f.has(status):
            state = str(f.get(status))
            if state in ("Slave", "Master") or time.monotonic() > deadline:
                break
            time.sleep(poll_s)
        return {"enabled": True, "status": state, "feature": enable}

    def log_event(self, event: dict, host_ns: int | None = None) -> None:
        self.events.append({**event, "host_ns": time.monotonic_ns() if host_ns is None else host_ns})

    def close(self) -> None:
        self.camera.close()
