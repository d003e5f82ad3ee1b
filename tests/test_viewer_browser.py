"""The viewer (`recon view`, /view) in headless Chromium: a drag renders a different pose, the spot
reading equals `recon render` at the pose and time the page shows, the point-over-time plot equals
temperature renders at its times, the status page embeds the viewer, nothing leaves the server.

Skips like tests/test_server_browser.py where Chromium or the Playwright driver is missing. The
screenshot is kept as tests/artifacts/viewer.png (or under $THERMAL4D_ARTIFACTS).
"""
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import server
from tests.chromium import ARGS, ARTIFACTS, CHROMIUM, playwright
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.render import load_run, render_frame
from recon.view import RenderService

sync_api = playwright(module_level=True)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewb")
    data, out = root / "data", root / "run"
    simulate_dataset(data, SimulateConfig(frames=4, width=40, height=30, seed=1, points=300))
    subprocess.run([sys.executable, "-m", "recon", "run", str(data), "--out", str(out), "--iterations", "20",
                    "--threads", "1"], check=True, capture_output=True)
    return out


SAME_POSE = ("(m) => { const c = window.viewer.last.c2w.flat(), f = m.flat();"
             " return Math.max(...c.map((v, i) => Math.abs(v - f[i]))) < 1e-6 && !window.viewer.inflight; }")
OTHER_POSE = ("(m) => { const c = window.viewer.last.c2w.flat(), f = m.flat();"
              " return Math.max(...c.map((v, i) => Math.abs(v - f[i]))) > 1e-3 && !window.viewer.inflight"
              " && !window.viewer.dirty; }")


def recon_render_kelvin(run: Path, header: dict, tmp: Path) -> np.ndarray:
    """`recon render` at the page's render pose, time and intrinsics -> kelvin (H, W)."""
    (tmp / "pose.json").write_text(json.dumps(header["c2w"]))
    cam = header["camera"]
    subprocess.run([sys.executable, "-m", "recon", "render", str(run), "--time", repr(header["t"]),
                    "--pose", str(tmp / "pose.json"), "--out", str(tmp / "r"),
                    *[a for k in ("fx", "fy", "cx", "cy", "width", "height") for a in (f"--{k}", repr(cam[k]))]],
                   check=True, capture_output=True)
    scale = json.loads((run / "scene.json").read_text())["thermal_scale_k"]
    return np.asarray(Image.open(tmp / "r_thermal.png")).astype(np.float64) * scale


def test_viewer_in_chromium(run, tmp_path):
    service = RenderService.from_run(run)
    requests, errors = [], []
    with server.serve("127.0.0.1", 0, run_dir=run, renderer=service) as handle, \
            sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1050}, accept_downloads=True)
        page.on("request", lambda r: requests.append(r.url))
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.goto(handle.url + "view")
        page.wait_for_function("() => window.viewer.last !== null", timeout=30_000)
        first = page.evaluate("() => window.viewer.last.c2w")
        before = page.evaluate("() => document.getElementById('rgb').toDataURL()")

        # a drag on the RGB view orbits: a render at another pose, a different picture
        box = page.locator("#rgb").bounding_box()
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        page.mouse.move(box["x"] + box["width"] / 2 + 90, box["y"] + box["height"] / 2 + 25, steps=10)
        page.mouse.up()
        page.wait_for_function(OTHER_POSE, arg=first, timeout=30_000)
        header = page.evaluate("() => window.viewer.last")
        assert not np.allclose(header["c2w"], first, atol=1e-3)
        assert page.evaluate("() => document.getElementById('rgb').toDataURL()") != before
        assert re.search(r"t = 0\.500 · camera at", page.inner_text("#pose"))

        # spot reading under the cursor = `recon render` at that pose and time, within 0.1 K
        tb = page.locator("#thermal").bounding_box()
        page.mouse.move(tb["x"] + tb["width"] * 0.5 + 3, tb["y"] + tb["height"] * 0.45)
        page.wait_for_function("() => document.getElementById('spot').dataset.kelvin !== undefined", timeout=10_000)
        spot = page.evaluate("() => ({...document.getElementById('spot').dataset})")
        x, y, kelvin = int(spot["x"]), int(spot["y"]), float(spot["kelvin"])
        ref = recon_render_kelvin(run, header, tmp_path)
        assert abs(ref[y, x] - kelvin) < 0.1, (ref[y, x], kelvin)
        celsius = float(re.match(r"(-?[\d.]+) °C", page.inner_text("#spot")).group(1))
        assert abs(celsius - (kelvin - 273.15)) < 0.01
        page.select_option("#unit", "K")
        page.mouse.move(tb["x"] + tb["width"] * 0.5 + 3, tb["y"] + tb["height"] * 0.45 + 1)
        assert re.match(r"[\d.]+ K at", page.inner_text("#spot"))
        page.select_option("#unit", "C")

        # box: min / max / mean of the kelvin shown
        page.click("button[data-tool=box]")
        page.mouse.move(tb["x"] + 40, tb["y"] + 40)
        page.mouse.down()
        page.mouse.move(tb["x"] + tb["width"] - 40, tb["y"] + tb["height"] - 40, steps=4)
        page.mouse.up()
        stats = page.evaluate("() => window.viewer.boxResult")
        k = np.asarray(page.evaluate("() => Array.from(window.viewer.kelvin)")).reshape(header["height"], header["width"])
        bx = page.evaluate("() => window.viewer.box")
        sel = k[min(bx[1], bx[3]):max(bx[1], bx[3]) + 1, min(bx[0], bx[2]):max(bx[0], bx[2]) + 1]
        assert stats["min"] == pytest.approx(sel.min(), abs=1e-3) and stats["max"] == pytest.approx(sel.max(), abs=1e-3)
        assert stats["mean"] == pytest.approx(sel.mean(), abs=1e-3)

        # line profile: a plot
        page.click("button[data-tool=line]")
        page.mouse.move(tb["x"] + 20, tb["y"] + tb["height"] / 2)
        page.mouse.down()
        page.mouse.move(tb["x"] + tb["width"] - 20, tb["y"] + tb["height"] / 2, steps=4)
        page.mouse.up()
        assert page.locator("#line-chart path").count() == 1

        # keyboard: R goes back to the starting camera (the drag above turned away from the object)
        page.keyboard.press("r")
        page.wait_for_function(SAME_POSE, arg=first, timeout=30_000)

        # point over time: the plotted temperatures are temperature renders at those times
        page.click("button[data-tool=point]")
        alpha = service.render(np.asarray(first), 0.5, header["width"], header["height"])["alpha"]
        py, px = np.unravel_index(np.argmax(alpha), alpha.shape)      # the most opaque pixel: a surface
        page.mouse.click(tb["x"] + (px + 0.5) * tb["width"] / header["width"],
                         tb["y"] + (py + 0.5) * tb["height"] / header["height"])
        try:
            page.wait_for_function("() => window.viewer.series !== null", timeout=30_000)
        except sync_api.TimeoutError:
            raise AssertionError(page.inner_text("#series-info")) from None
        series = page.evaluate("() => window.viewer.series")
        plotted = page.get_attribute("#series-chart path", "d")
        inside = [s for s in series["samples"] if s["kelvin"] is not None]
        assert len(inside) >= 8 and plotted.count("L") == len(inside) - 1
        model, facts = load_run(run)
        k_min, k_max = facts["thermal_range_k"]
        cam, _ = service.camera(np.asarray(series["c2w"]), header["width"], header["height"])
        for s in inside[::3]:
            ref_t = render_frame(model, "thermal", s["time"], cam)[..., 0] * (k_max - k_min) + k_min
            assert abs(float(ref_t[s["y"], s["x"]]) - s["kelvin"]) < 0.1, s

        # exports: PNG of the view, its temperatures and the time series as CSV
        for button, suffix in (("#png", ".png"), ("#csv", ".csv"), ("#series-csv", ".csv")):
            with page.expect_download() as dl:
                page.click(button)
            path = tmp_path / dl.value.suggested_filename
            dl.value.save_as(path)
            assert path.suffix == suffix and path.stat().st_size > 100
        rows = [r for r in (tmp_path / "temperature_t0.500.csv").read_text().splitlines() if not r.startswith("#")]
        assert len(rows) == header["height"] and len(rows[0].split(",")) == header["width"]

        # keyboard: W moves forward (another pose), . steps time
        page.click("button[data-tool=navigate]")
        page.keyboard.press("w")
        page.wait_for_function(OTHER_POSE, arg=first, timeout=30_000)
        page.keyboard.press(".")
        page.wait_for_function("() => window.viewer.last.t > 0.505", timeout=30_000)

        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "viewer.png"), full_page=True)

        # the status page shows the same viewer as a panel when a renderer is attached
        viewer_errors = list(errors)
        page.goto(handle.url)
        page.wait_for_function("() => document.getElementById('viewer-card').style.display === ''", timeout=30_000)
        frame = page.frame_locator("#viewer-frame")
        frame.locator("#pose").filter(has_text="render: t =").wait_for(timeout=30_000)
        browser.close()
    assert requests and all(u.startswith(handle.url) or u.startswith(("data:", "blob:")) for u in requests), \
        [u for u in requests if not u.startswith(handle.url)]
    assert not viewer_errors, viewer_errors
    # the status page's endpoints answer 503 until something is published (no session here): expected
    assert not [e for e in errors if "503" not in e], errors
