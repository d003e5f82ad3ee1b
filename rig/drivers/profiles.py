"""Which profile a GigE Vision thermal camera gets, from the features its own GenICam XML declares:

  flir-irformat   an `IRFormat` enumeration: FLIR A400/A500/A700, A50/A70 (and the science
                  cameras pyFlir drives the same way): temperature-linear 10 mK / 100 mK or
                  Radiometric counts with the camera's calibration (rig/drivers/flir.py)
  flir-tlinear    `TemperatureLinearMode` + `TemperatureLinearResolution`: FLIR A35/A65, Ax5
                  line, A6xx science cameras: 40 mK / 400 mK per count (rig/drivers/flir.py)
  generic         anything else with a Mono PixelFormat: counts; kelvin only through a stated
                  linear map; marked non-radiometric (rig/drivers/generic_gige.py)

Features, not model names, decide: a firmware that renames a feature gets the profile its
features allow, and `rig devices` shows which one each camera gets."""
from __future__ import annotations

from rig.drivers.flir import FlirA700, FlirTLinear
from rig.drivers.generic_gige import GenericGigE, KelvinMap
from rig.drivers.gige.camera import GigECamera
from rig.drivers.thermal_camera import ThermalCamera

PROFILES = {"flir-irformat": FlirA700, "flir-tlinear": FlirTLinear, "generic": GenericGigE}


def choose_profile(features) -> str:
    """The profile name a camera's features allow (see the module docstring)."""
    if features.has("IRFormat"):
        return "flir-irformat"
    if features.has("TemperatureLinearMode") and features.has("TemperatureLinearResolution"):
        return "flir-tlinear"
    return "generic"


def open_thermal_camera(url: str, profile: str = "auto", ir_format: str = "TemperatureLinear10mK",
                        kelvin_map: KelvinMap | None = None, frame_rate: float | None = None) -> ThermalCamera:
    """Open, choose the profile (or take the one named), configure; the control channel is
    released again if configuring refuses the camera."""
    if profile != "auto" and profile not in PROFILES:
        raise ValueError(f"--profile {profile!r}: expected auto or one of {', '.join(PROFILES)}")
    gige = GigECamera.open(url)
    try:
        name = choose_profile(gige.features) if profile == "auto" else profile
        if kelvin_map is not None and name != "generic":
            raise ValueError(f"--kelvin-map is for cameras without radiometric features; "
                             f"{gige.info.manufacturer if gige.info else url} gets the {name} profile, "
                             f"which reads kelvin from the camera")
        cam = PROFILES[name](gige)
        if name == "flir-irformat":
            cam.configure(ir_format, frame_rate=frame_rate or 30.0)
        else:
            cam.configure(kelvin_map=kelvin_map, frame_rate=frame_rate)
        return cam
    except BaseException:
        gige.close()        # the control channel's heartbeat must not outlive a refusal
        raise


def describe(url: str) -> dict:
    """For `rig devices`: the profile a camera gets and the features that decided it (the control
    channel is taken and released; a camera another host controls is reported as such)."""
    try:
        with GigECamera.open(url) as gige:
            f = gige.features
            name = choose_profile(f)
            formats = list(f.node("PixelFormat").symbolics) if f.has("PixelFormat") else []
            return {"profile": name, "radiometric": name != "generic", "pixel_formats": formats}
    except Exception as exc:      # noqa: BLE001 - listing devices must not fail on one camera
        return {"profile": None, "error": f"{type(exc).__name__}: {exc}"}
