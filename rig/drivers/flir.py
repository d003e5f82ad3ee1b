"""FLIR A700 profile: IRFormat, object parameters, NUC, counts -> kelvin.

The A700 streams Mono16 640x480 at 30 Hz. What a count means depends on the
IRFormat in force *when the frame was produced* (a change only reaches the
stream after a fresh AcquisitionStart):

- TemperatureLinear10mK: T = counts * 0.01 K (ceiling 655.35 K = 382 C)
- TemperatureLinear100mK: T = counts * 0.1 K (use it for the 0..650 C range)
- Radiometric: counts = J1 * radiance + J0; the host removes reflected and
  atmospheric radiance with the object parameters (FLIR's published model) and
  inverts Planck's law with the calibration constants R, B, F.

In the temperature-linear formats the camera applies the object parameters
itself. `FlirA700` tags every frame with the format, scale and parameters of
its acquisition epoch, found by latching the device clock before each start.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from rig.drivers.gige.camera import GigECamera
from rig.drivers.gige.stream import Frame, GvspStream, StreamConfig

log = logging.getLogger(__name__)

IR_FORMAT_SCALE_K = {"TemperatureLinear10mK": 0.01, "TemperatureLinear100mK": 0.1}
IR_FORMATS = ("TemperatureLinear10mK", "TemperatureLinear100mK", "Radiometric")
A700_WIDTH, A700_HEIGHT, A700_FPS = 640, 480, 30.0

# GenICam feature name of each ObjectParameters field
OBJECT_FEATURES = {
    "emissivity": "ObjectEmissivity",
    "reflected_k": "ReflectedTemperature",
    "atmospheric_k": "AtmosphericTemperature",
    "distance_m": "ObjectDistance",
    "relative_humidity": "RelativeHumidity",
    "window_k": "WindowTemperature",
    "window_transmission": "WindowTransmission",
}
CALIBRATION_FEATURES = ("R", "B", "F", "X", "alpha1", "alpha2", "beta1", "beta2", "J0", "J1")


@dataclass
class ObjectParameters:
    emissivity: float = 0.95
    reflected_k: float = 293.15
    atmospheric_k: float = 293.15
    distance_m: float = 2.0
    relative_humidity: float = 0.5      # 0..1
    window_k: float = 293.15
    window_transmission: float = 1.0


@dataclass
class RadiometricCalibration:
    """Per-camera constants of FLIR's radiometric model (read from the camera)."""
    R: float = 16556.0
    B: float = 1428.0
    F: float = 1.0
    X: float = 1.9
    alpha1: float = 0.006569
    alpha2: float = 0.01262
    beta1: float = -0.002276
    beta2: float = -0.00667
    J0: int = 2000
    J1: float = 100.0


def atmospheric_transmission(p: ObjectParameters, c: RadiometricCalibration) -> float:
    """FLIR's two-band atmospheric model over the object distance."""
    tc = p.atmospheric_k - 273.15
    h2o = p.relative_humidity * math.exp(1.5587 + 0.06939 * tc - 0.00027816 * tc ** 2
                                         + 0.00000068455 * tc ** 3)
    sd = math.sqrt(max(p.distance_m, 0.0))
    return (c.X * math.exp(-sd * (c.alpha1 + c.beta1 * math.sqrt(h2o)))
            + (1 - c.X) * math.exp(-sd * (c.alpha2 + c.beta2 * math.sqrt(h2o))))


def radiance(kelvin, c: RadiometricCalibration):
    return c.R / (np.exp(c.B / np.asarray(kelvin, dtype=np.float64)) - c.F)


def _background(p: ObjectParameters, c: RadiometricCalibration) -> tuple[float, float]:
    """-> (gain on object radiance, additive radiance) at the detector."""
    tau = atmospheric_transmission(p, c)
    tw = p.window_transmission
    gain = tw * tau * p.emissivity
    add = (tw * tau * (1 - p.emissivity) * radiance(p.reflected_k, c)
           + tw * (1 - tau) * radiance(p.atmospheric_k, c) + (1 - tw) * radiance(p.window_k, c))
    return gain, float(add)


def radiometric_to_kelvin(counts: np.ndarray, p: ObjectParameters, c: RadiometricCalibration) -> np.ndarray:
    gain, add = _background(p, c)
    rad_obj = ((counts.astype(np.float64) - c.J0) / c.J1 - add) / gain
    with np.errstate(divide="ignore", invalid="ignore"):
        t = c.B / np.log(c.R / rad_obj + c.F)
    return np.where(rad_obj > 0, t, np.nan)


def kelvin_to_radiometric(kelvin: np.ndarray, p: ObjectParameters, c: RadiometricCalibration) -> np.ndarray:
    gain, add = _background(p, c)
    s = c.J1 * (gain * radiance(kelvin, c) + add) + c.J0
    return np.clip(np.rint(s), 0, 65535).astype(np.uint16)


def counts_to_kelvin(counts: np.ndarray, ir_format: str, params: ObjectParameters | None = None,
                     calibration: RadiometricCalibration | None = None) -> np.ndarray:
    """(H, W) uint16 counts -> (H, W) float64 kelvin for the given IRFormat."""
    if ir_format in IR_FORMAT_SCALE_K:
        return counts.astype(np.float64) * IR_FORMAT_SCALE_K[ir_format]
    if ir_format == "Radiometric":
        return radiometric_to_kelvin(counts, params or ObjectParameters(),
                                     calibration or RadiometricCalibration())
    raise ValueError(f"unknown IRFormat {ir_format!r}; expected one of {IR_FORMATS}")


def kelvin_to_counts(kelvin: np.ndarray, ir_format: str, params: ObjectParameters | None = None,
                     calibration: RadiometricCalibration | None = None) -> np.ndarray:
    """Inverse of `counts_to_kelvin` (what the camera does), clipped to uint16."""
    if ir_format in IR_FORMAT_SCALE_K:
        return np.clip(np.rint(np.asarray(kelvin) / IR_FORMAT_SCALE_K[ir_format]), 0, 65535).astype(np.uint16)
    if ir_format == "Radiometric":
        return kelvin_to_radiometric(kelvin, params or ObjectParameters(),
                                     calibration or RadiometricCalibration())
    raise ValueError(f"unknown IRFormat {ir_format!r}; expected one of {IR_FORMATS}")


@dataclass
class Epoch:
    """What was in force from one AcquisitionStart on."""
    start_ticks: int
    ir_format: str
    params: ObjectParameters
    calibration: RadiometricCalibration | None

    @property
    def scale_k(self) -> float | None:
        return IR_FORMAT_SCALE_K.get(self.ir_format)

    def meta(self) -> dict:
        return {"ir_format": self.ir_format, "scale_k": self.scale_k,
                "object_parameters": asdict(self.params),
                "calibration": asdict(self.calibration) if self.calibration else None}


class UnsupportedCamera(ValueError):
    """The device lacks a feature this profile needs; the message names the camera and the feature."""


@dataclass
class FlirA700:
    """FLIR A700 on top of a `GigECamera`. `next_frame()` returns frames tagged with
    `meta` = IRFormat, kelvin/count scale, object parameters of their acquisition."""
    camera: GigECamera
    epochs: list[Epoch] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)     # NUCs and format changes, host time
    _epoch_index: int = 0

    @classmethod
    def open(cls, url: str, **kw) -> FlirA700:
        return cls(GigECamera.open(url, **kw))

    @property
    def features(self):
        return self.camera.features

    def configure(self, ir_format: str = "TemperatureLinear10mK", width: int = A700_WIDTH,
                  height: int = A700_HEIGHT, frame_rate: float | None = A700_FPS,
                  params: ObjectParameters | None = None) -> None:
        """Mono16, geometry, rate and IRFormat (before `start`)."""
        if ir_format not in IR_FORMATS:
            raise ValueError(f"unknown IRFormat {ir_format!r}; expected one of {IR_FORMATS}")
        f = self.features
        missing = [n for n in ("PixelFormat", "Width", "Height", "IRFormat") if not f.has(n)]
        if missing:
            info = self.camera.info
            name = f"{info.manufacturer} {info.model}".strip() if info else "the camera"
            raise UnsupportedCamera(
                f"{name} has no GenICam feature {', '.join(missing)}: it is not a radiometric FLIR "
                f"A400/A500/A700, the only thermal cameras `rig capture` records today; capture "
                f"without --camera (simulated thermal camera) or use one of those")
        f.set("PixelFormat", "Mono16")
        f.set("Width", width)
        f.set("Height", height)
        if frame_rate and f.has("AcquisitionFrameRate"):
            f.set("AcquisitionFrameRate", float(frame_rate))
        f.set("IRFormat", ir_format)
        self.set_object_parameters(params or ObjectParameters())

    def set_object_parameters(self, params: ObjectParameters) -> None:
        for name, feature in OBJECT_FEATURES.items():
            if self.features.has(feature):
                self.features.set(feature, float(getattr(params, name)))

    def object_parameters(self) -> ObjectParameters:
        f = self.features
        return ObjectParameters(**{name: float(f.get(feat)) for name, feat in OBJECT_FEATURES.items()
                                   if f.has(feat)})

    def calibration(self) -> RadiometricCalibration | None:
        f = self.features
        if not all(f.has(n) for n in CALIBRATION_FEATURES):
            return None
        return RadiometricCalibration(**{n: f.get(n) for n in CALIBRATION_FEATURES})

    def start(self, config: StreamConfig | None = None) -> GvspStream:
        """AcquisitionStart, opening a new epoch at the latched device time."""
        start_ticks, _ = self.camera.device.latch_timestamp()
        self.epochs.append(Epoch(start_ticks, self.features.get("IRFormat"),
                                 self.object_parameters(), self.calibration()))
        return self.camera.start_stream(config)

    def set_ir_format(self, ir_format: str, host_ns: int | None = None) -> None:
        """Change IRFormat; while streaming, restart acquisition so it takes effect."""
        streaming = self.camera.stream is not None
        if streaming:
            self.camera.stop_acquisition()
        self.features.set("IRFormat", ir_format)
        self.events.append({"event": "ir_format", "ir_format": ir_format,
                            "host_ns": time.monotonic_ns() if host_ns is None else host_ns})
        if streaming:
            self.start()

    def nuc(self, host_ns: int | None = None) -> None:
        """Non-uniformity correction (the shutter closes; frames pause or freeze). Logged with
        the host time it was commanded (`host_ns`, default now) and acknowledged."""
        host_ns = time.monotonic_ns() if host_ns is None else host_ns
        self.features.execute("NUCAction")         # returns once the camera acks (PENDING_ACK first)
        self.events.append({"event": "nuc", "source": "command", "host_ns": host_ns,
                            "done_host_ns": time.monotonic_ns()})

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

    def kelvin(self, frame: Frame) -> np.ndarray:
        """(H, W) float64 kelvin of a tagged frame."""
        m = frame.meta
        cal = RadiometricCalibration(**m["calibration"]) if m.get("calibration") else None
        return counts_to_kelvin(frame.array(), m["ir_format"], ObjectParameters(**m["object_parameters"]), cal)

    def close(self) -> None:
        self.camera.close()
