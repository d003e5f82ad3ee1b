"""Camera profiles chosen from the device's own GenICam XML (rig/drivers/profiles.py), each against
the project's fake GigE camera with its features as that family names them (tests/fakes/fake_gige.py
VARIANTS: a700 = IRFormat, ax5 = TemperatureLinearMode/Resolution + Mono14, generic = none), end to
end through `rig capture` into a session whose kelvin equal the scene's within one count."""
import json
import time

import cv2
import numpy as np
import pytest

import server
from rig.cli import main as rig_main
from rig.drivers.flir import UnsupportedCamera
from rig.drivers.generic_gige import KelvinMap
from rig.drivers.gige import GigECamera
from rig.drivers.profiles import choose_profile, describe, open_thermal_camera
from rig.info import session_info
from rig.session import open_session
from tests.test_server_endpoints import get
from tests.fakes.fake_gige import GENERIC_GAIN_K, GENERIC_OFFSET_K, FakeConfig, FakeGigECamera

W, H = 64, 48
KELVIN = 290.0 + 30.0 * np.arange(W)[None, :].repeat(H, 0) / W       # static, so any frame is exact


def scene_at(shape) -> np.ndarray:
    """The fake's scene at the streamed size (a FLIR profile sets 640x480; the fake resizes)."""
    if shape == KELVIN.shape:
        return KELVIN
    return cv2.resize(KELVIN.astype(np.float32), shape[::-1], interpolation=cv2.INTER_AREA).astype(np.float64)


def fake(variant: str) -> FakeGigECamera:
    return FakeGigECamera(FakeConfig(width=W, height=H, variant=variant, source=lambda t: KELVIN))


@pytest.mark.parametrize("variant,profile,step_k", [("a700", "flir-irformat", 0.01), ("ax5", "flir-tlinear", 0.04),
                                                    ("generic", "generic", GENERIC_GAIN_K)])
def test_each_family_gets_its_profile_and_records_kelvin(variant, profile, step_k, tmp_path):
    out = tmp_path / "s"
    extra = ["--kelvin-map", f"{GENERIC_GAIN_K},{GENERIC_OFFSET_K}"] if variant == "generic" else []
    with fake(variant) as cam:
        assert describe(cam.url)["profile"] == profile
        code = rig_main(["capture", "--camera", cam.url, "--duration", "1.5", "--out", str(out), "--quiet", *extra])
    assert code == 0
    s = open_session(out)
    assert s.meta["thermal"]["profile"] == profile
    assert s.meta["thermal"]["radiometric"] == (variant != "generic")
    frame = s.thermal_frame(len(s.thermal) // 2)
    kelvin = frame.kelvin()
    assert np.abs(kelvin - scene_at(kelvin.shape)).max() <= step_k / 2 + 1e-3
    info = session_info(s)["streams"]["thermal"]
    assert info["profile"] == profile and info["complete"] == info["frames"] > 20


def test_a_generic_camera_without_a_map_records_counts_and_says_so(tmp_path, capsys):
    out = tmp_path / "s"
    with fake("generic") as cam:
        assert rig_main(["capture", "--camera", cam.url, "--duration", "1", "--out", str(out), "--quiet"]) == 0
    s = open_session(out)
    assert s.meta["thermal"]["radiometric"] is False and s.meta["thermal"]["kelvin_map"] is None
    with pytest.raises(ValueError, match="--kelvin-map"):
        s.thermal_frame(0).kelvin()
    capsys.readouterr()
    assert rig_main(["info", str(out)]) == 0
    assert "NOT radiometric: counts only" in capsys.readouterr().out
    with server.serve(port=0, session_dir=out, session_poll_s=0.05) as handle:     # the status page says so too
        deadline = time.monotonic() + 10
        while (status := get(handle, "/api/capture"))[0] != 200 and time.monotonic() < deadline:
            time.sleep(0.1)
    thermal = json.loads(status[2])["streams"]["thermal"]
    assert thermal["profile"] == "generic" and thermal["radiometric"] is False


def test_a_profile_the_camera_cannot_take_is_one_line_and_releases_the_camera():
    with fake("ax5") as cam:
        with pytest.raises(UnsupportedCamera) as exc:
            open_thermal_camera(cam.url, profile="flir-irformat")
        assert "FLIR A65" in str(exc.value) and "IRFormat" in str(exc.value) and "\n" not in str(exc.value)
        with pytest.raises(ValueError, match="--kelvin-map is for cameras without radiometric features"):
            open_thermal_camera(cam.url, kelvin_map=KelvinMap(0.01))
        with GigECamera.open(cam.url, exclusive=True) as again:    # control was released both times
            assert choose_profile(again.features) == "flir-tlinear"


def test_kelvin_map_from_a_flag_or_a_file(tmp_path):
    assert KelvinMap.parse("0.02,200") == KelvinMap(0.02, 200.0)
    assert KelvinMap.parse("0.1").offset_k == 0.0
    f = tmp_path / "map.json"
    f.write_text(json.dumps({"gain_k": 0.05, "offset_k": 10}))
    assert KelvinMap.parse(str(f)) == KelvinMap(0.05, 10.0, str(f))
    for bad in ("abc", "0,1", "1,2,3"):
        with pytest.raises(ValueError, match="--kelvin-map"):
            KelvinMap.parse(bad)
    f.write_text("{}")
    with pytest.raises(ValueError, match="map.json"):
        KelvinMap.parse(str(f))


def test_ptp_is_enabled_where_offered_and_sync_fits_only_the_offset(tmp_path):
    """IEEE 1588: `rig capture` enables PtpEnable, waits for the port to settle and records it;
    a slave's clock runs at the grandmaster's rate, so sync keeps rate 1 and fits the offset only.
    The fake's free-running clock is 300 ppm fast, drift-free once a slave."""
    from rig.sync import synchronise_session
    out = {}
    for ptp in ("slave", None):
        out[ptp] = tmp_path / f"s-{ptp}"
        with FakeGigECamera(FakeConfig(width=W, height=H, source=lambda t: KELVIN, ptp=ptp,
                                       clock_drift_ppm=300.0)) as cam:
            assert rig_main(["capture", "--camera", cam.url, "--duration", "1.5", "--out", str(out[ptp]),
                             "--quiet"]) == 0
    slave, plain = open_session(out["slave"]), open_session(out[None])
    assert slave.meta["thermal"]["ptp"] == {"enabled": True, "status": "Slave", "feature": "PtpEnable"}
    assert plain.meta["thermal"]["ptp"]["enabled"] is False
    assert synchronise_session(slave).thermal_clock["rate"] == 1.0
    assert synchronise_session(plain).thermal_clock["rate"] != 1.0            # fitted, as before
