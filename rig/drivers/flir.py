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
from dataclasses import dataclass

import numpy as np

from rig.drivers.gige.stream import Frame
from rig.drivers.thermal_camera import Epoch, ThermalCamera, UnsupportedCamera  # noqa: F401 (re-exported)

log = logging.getLogger(__name__)

IR_FORMAT_SCALE_K = {"TemperatureLinear10mK": 0.01, "TemperatureLinear100mK": 0.1,
                     # the Ax5 family's TemperatureLinearResolution High / Low (FlirTLinear below)
                     "TemperatureLinear40mK": 0.04, "TemperatureLinear400mK": 0.4}
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
class FlirA700(ThermalCamera):
    """The FLIR IRFormat family (A400/A500/A700, A50/A70; the science cameras pyFlir drives
    through the same feature) on top of a `GigECamera`. `next_frame()` returns frames tagged
    with `meta` = IRFormat, kelvin/count scale, object parameters of their acquisition."""

    profile = "flir-irformat"

    def configure(self, ir_format: str = "TemperatureLinear10mK", width: int = A700_WIDTH,
                  height: int = A700_HEIGHT, frame_rate: float | None = A700_FPS,
                  params: ObjectParameters | None = None) -> None:
        """Mono16, geometry, rate and IRFormat (before `start`)."""
        if ir_format not in IR_FORMATS:
            raise ValueError(f"unknown IRFormat {ir_format!r}; expected one of {IR_FORMATS}")
        self.missing(("PixelFormat", "Width", "Height", "IRFormat"),
                     "it is not a radiometric FLIR of the IRFormat family (A400/A500/A700); "
                     "`rig capture --profile auto` picks the profile the camera's features allow")
        f = self.features
        f.set("PixelFormat", "Mono16")
        f.set("Width", width)
        f.set("Height", height)
        if frame_rate and f.has("AcquisitionFrameRate"):
            f.set("AcquisitionFrameRate", float(frame_rate))
        self.frame_rate = frame_rate
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

    def new_epoch(self, start_ticks: int) -> Epoch:
        fmt = self.features.get("IRFormat")
        return Epoch(start_ticks, fmt, IR_FORMAT_SCALE_K.get(fmt), params=self.object_parameters(),
                     calibration=self.calibration())

    def set_ir_format(self, ir_format: str, host_ns: int | None = None) -> None:
        """Change IRFormat; while streaming, restart acquisition so it takes effect."""
        streaming = self.camera.stream is not None
        if streaming:
            self.camera.stop_acquisition()
        self.features.set("IRFormat", ir_format)
        self.log_event({"event": "ir_format", "ir_format": ir_format}, host_ns)
        if streaming:
            self.start()

    def nuc(self, host_ns: int | None = None) -> None:
        """Non-uniformity correction (the shutter closes; frames pause or freeze). Logged with
        the host time it was commanded (`host_ns`, default now) and acknowledged."""
        host_ns = time.monotonic_ns() if host_ns is None else host_ns
        self.features.execute("NUCAction")         # returns once the camera acks (PENDING_ACK first)
        self.events.append({"event": "nuc", "source": "command", "host_ns": host_ns,
                            "done_host_ns": time.monotonic_ns()})

    def kelvin(self, frame: Frame) -> np.ndarray:
        """(H, W) float64 kelvin of a tagged frame."""
        m = frame.meta
        cal = RadiometricCalibration(**m["calibration"]) if m.get("calibration") else None
        return counts_to_kelvin(frame.array(), m["ir_format"], ObjectParameters(**m["object_parameters"]), cal)


# TemperatureLinearResolution entry -> the IRFormat-style name of its scale (IR_FORMAT_SCALE_K)
TLINEAR_RESOLUTION = {"High": "TemperatureLinear40mK", "Low": "TemperatureLinear400mK"}


@dataclass
class FlirTLinear(ThermalCamera):
    """The FLIR families that name their temperature-linear output differently (A35/A65 and the
    Ax5 line; the same features appear in public code for A6xx science cameras): no IRFormat;
    `TemperatureLinearMode` On makes counts kelvin, `TemperatureLinearResolution` High = 0.04 K
    per count, Low = 0.4 K (FLIR's Ax5 interface description, as used by public Spinnaker, eBUS
    and Harvesters scripts). Pixels are Mono16 or Mono14 (14 bits in 16)."""

    profile = "flir-tlinear"

    def configure(self, resolution: str = "High", frame_rate: float | None = None, **_) -> None:
        if resolution not in TLINEAR_RESOLUTION:
            raise ValueError(f"TemperatureLinearResolution {resolution!r}: expected High or Low")
        self.missing(("PixelFormat", "TemperatureLinearMode", "TemperatureLinearResolution"),
                     "it is not a temperature-linear FLIR (Ax5 family)")
        f = self.features
        formats = f.node("PixelFormat").symbolics
        pixel = next((p for p in ("Mono16", "Mono14") if p in formats), None)
        if pixel is None:
            raise UnsupportedCamera(f"{self.name} offers PixelFormat {', '.join(formats)}, none of Mono16/Mono14: "
                                    f"temperature-linear counts need 14 or 16 bits")
        f.set("PixelFormat", pixel)
        f.set("TemperatureLinearMode", "On")
        f.set("TemperatureLinearResolution", resolution)
        if frame_rate and f.has("AcquisitionFrameRate"):
            f.set("AcquisitionFrameRate", float(frame_rate))
        self.frame_rate = float(f.get("AcquisitionFrameRate")) if f.has("AcquisitionFrameRate") else frame_rate

    def new_epoch(self, start_ticks: int) -> Epoch:
        fmt = TLINEAR_RESOLUTION[self.features.get("TemperatureLinearResolution")]
        return Epoch(start_ticks, fmt, IR_FORMAT_SCALE_K[fmt])
