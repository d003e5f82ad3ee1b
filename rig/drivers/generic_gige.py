"""Any GigE Vision camera (GenICam SFNC features only): counts, not temperatures, unless the user
states a linear map from counts to kelvin (a flag or a calibration file). Sessions recorded with
this profile are marked non-radiometric.

    cam = GenericGigE.open("gige://192.168.1.30")
    cam.configure(kelvin_map=KelvinMap(0.01, 0.0))      # or None: counts only
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from rig.drivers.thermal_camera import Epoch, ThermalCamera, UnsupportedCamera

# Unpacked monochrome formats the receiver stores as they arrive (8 bits, or 10-16 in 16),
# best first. Packed formats (Mono12p, ...) are not decoded.
MONO_FORMATS = ("Mono16", "Mono14", "Mono12", "Mono10", "Mono8")


@dataclass
class KelvinMap:
    """kelvin = counts x gain_k + offset_k, as the user states it (not the camera)."""
    gain_k: float
    offset_k: float = 0.0
    source: str = "flag"

    @classmethod
    def parse(cls, text: str) -> "KelvinMap":
        """'GAIN,OFFSET' (kelvin per count, kelvin at count 0) or a JSON file
        {"gain_k": 0.01, "offset_k": 0}. ValueError naming the value or file otherwise."""
        path = Path(text)
        if path.suffix == ".json" or path.is_file():
            try:
                d = json.loads(path.read_text())
                return cls(float(d["gain_k"]), float(d.get("offset_k", 0.0)), str(path))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"{path}: not a counts-to-kelvin map ({exc}); expected "
                                 f'{{"gain_k": 0.01, "offset_k": 0.0}}') from None
        try:
            parts = [float(v) for v in text.split(",")]
        except ValueError:
            parts = []
        if len(parts) not in (1, 2) or not parts[0] > 0:
            raise ValueError(f"--kelvin-map {text!r}: expected GAIN[,OFFSET] (kelvin per count > 0, kelvin at "
                             f"count 0) or a JSON file")
        return cls(parts[0], parts[1] if len(parts) == 2 else 0.0)

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class GenericGigE(ThermalCamera):
    """A GigE Vision camera with the SFNC's Width, Height and a Mono PixelFormat."""

    profile = "generic"
    kelvin_map: KelvinMap | None = None

    def configure(self, kelvin_map: KelvinMap | None = None, pixel_format: str | None = None,
                  frame_rate: float | None = None, **_) -> None:
        """The deepest unpacked Mono format (or `pixel_format`), the camera's own geometry, and
        `frame_rate` if given and the camera has AcquisitionFrameRate."""
        self.missing(("PixelFormat", "Width", "Height"), "not a GenICam SFNC image camera")
        f = self.features
        offered = f.node("PixelFormat").symbolics
        wanted = [pixel_format] if pixel_format else MONO_FORMATS
        pick = next((p for p in wanted if p in offered and p in MONO_FORMATS), None)
        if pick is None:
            raise UnsupportedCamera(f"{self.name} offers PixelFormat {', '.join(offered)}; thermal4d records "
                                    f"{', '.join(MONO_FORMATS)} (unpacked){' and not ' + pixel_format if pixel_format else ''}")
        f.set("PixelFormat", pick)
        if frame_rate and f.has("AcquisitionFrameRate"):
            f.set("AcquisitionFrameRate", float(frame_rate))
        self.frame_rate = float(f.get("AcquisitionFrameRate")) if f.has("AcquisitionFrameRate") else frame_rate
        self.kelvin_map = kelvin_map

    def new_epoch(self, start_ticks: int) -> Epoch:
        m = self.kelvin_map
        return Epoch(start_ticks, "Counts", m.gain_k if m else None, m.offset_k if m else 0.0, radiometric=False)
