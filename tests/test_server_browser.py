"""The status page in headless Chromium during a real short simulated capture and real training.

Skips (never fails) where Chromium or the Playwright driver is missing (`make system-deps` installs
Debian's chromium; the `test` extra installs playwright; no browser is downloaded). The screenshot
is kept as tests/artifacts/status_page.png (or under $THERMAL4D_ARTIFACTS).
"""
import re
import subprocess
import sys
import threading
from pathlib import Path


import server
from tests.chromium import ARGS, ARTIFACTS, CHROMIUM, playwright
from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.live.publish import LivePublisher, TrainingFeed
from recon.scene import Scene
from recon.train.trainer import Trainer

sync_api = playwright(module_level=True)


def text_int(page, element_id: str) -> int:
    return int(re.match(r"\d+", page.inner_text(f"#{element_id}")).group())


class Training:
    """A real Trainer on a tiny simulated scene, stepping in a thread and publishing as it goes."""

    def __init__(self, root: Path):
        simulate_dataset(root / "data", SimulateConfig(variant="default", frames=6, width=48, height=36,
                                                       seed=3, points=600))
        cfg = make_config("dtg", iterations=100_000, eval_every=10**9, log_every=10**9, checkpoint_every=10**9)
        cfg.densify.every = 20
        cfg.loss.embedding_knn_sample = 256
        self.trainer = Trainer(cfg, Scene(load_dataset(root / "data")), log=lambda _: None)
        self.feed = TrainingFeed(LivePublisher(root / "run"), ring=6, status_every_s=0.3,
                                 metric_every_s=0.5, psnr_every_s=1.0, render_every_s=0.7)
        self.stop = threading.Event()
        self.error = None
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self):
        try:
            while not self.stop.is_set():
                self.feed.on_step(self.trainer, self.trainer.step())
            self.feed.finish(self.trainer)
        except Exception as exc:          # reported by the test, not lost in a thread
            self.error = exc


def test_status_page_shows_live_training_and_capture(tmp_path):
    session, run = tmp_path / "session", tmp_path / "run"
    capture = subprocess.Popen([sys.executable, "-m", "rig", "capture", "--duration", "4", "--out", str(session),
                                "--sim-scene", "synthetic", "--quiet"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    training = Training(tmp_path)
    handle = server.serve("127.0.0.1", 0, run_dir=run, session_dir=session, session_poll_s=0.3)
    training.thread.start()
    requests, errors = [], []
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.on("request", lambda r: requests.append(r.url))
            page.on("pageerror", lambda e: errors.append(str(e)))
            # a 503 ("not published yet") is logged by Chromium as a failed resource: expected early on
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" and "503" not in m.text else None)
            page.goto(handle.url)

            page.wait_for_function("() => /^\\d+/.test(document.getElementById('iteration').textContent)", timeout=60_000)
            first = text_int(page, "iteration")
            page.wait_for_function(f"() => parseInt(document.getElementById('iteration').textContent) > {first}",
                                   timeout=60_000)
            page.wait_for_function("() => ['rgb', 'thermal'].every(id => document.getElementById(id).naturalWidth > 0)",
                                   timeout=60_000)
            page.wait_for_function("() => document.querySelectorAll('#loss-chart path').length >= 2"
                                   " && document.querySelectorAll('#psnr-chart path').length >= 2", timeout=60_000)
            page.wait_for_function("() => document.getElementById('cap-state').textContent === 'closed'", timeout=90_000)
            assert text_int(page, "iteration") > first

            # the guard's events as the trainer records them: a drift warning reads as one, not as a rollback
            training.trainer.events += [
                {"iteration": 7, "reason": "the deformation moves the median Gaussian 0.3 scene extents: watched, "
                                           "not rolled back", "warning": True},
                {"iteration": 9, "reason": "thermal loss is nan", "rolled_back_to": 0, "lr_scale": 0.5}]
            page.wait_for_function("() => document.querySelectorAll('#events div').length === 2", timeout=10_000)
            shown = [page.inner_text(f"#events div:nth-child({i})") for i in (1, 2)]
            assert shown[0].startswith("⚠ warning at iteration 7: the deformation") and "rolled back to" not in shown[0]
            assert shown[1] == "⚠ divergence at iteration 9: thermal loss is nan; rolled back to iteration 0 with learning rates ×0.5"

            # the temperature under the cursor comes from the published raw kelvin
            box = page.locator("#thermal").bounding_box()
            page.mouse.move(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.5)
            page.wait_for_function("() => /°C at/.test(document.getElementById('readout').textContent)", timeout=10_000)
            celsius = float(re.match(r"(-?[\d.]+) °C", page.inner_text("#readout")).group(1))
            k_min, k_max = training.trainer.scene.k_min, training.trainer.scene.k_max
            assert k_min - 273.15 - 20 < celsius < k_max - 273.15 + 20

            # the time slider switches to a ring render
            page.locator("#time").fill("0")
            page.wait_for_function("() => document.getElementById('rgb').src.includes('/render/t00/')", timeout=10_000)
            page.locator("#latest").click()
            page.wait_for_function("() => document.getElementById('rgb').src.includes('/render/latest/')", timeout=10_000)
            page.wait_for_timeout(1500)             # one more poll, so the shot shows settled charts
            page.mouse.move(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.5)
            page.wait_for_function("() => /°C at/.test(document.getElementById('readout').textContent)", timeout=10_000)

            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            shot = ARTIFACTS / "status_page.png"
            page.screenshot(path=str(shot), full_page=True)
            print(f"\nstatus page screenshot: {shot}")
            capture_rows = page.inner_text("#capture")
            browser.close()
    finally:
        training.stop.set()
        training.thread.join(timeout=60)
        handle.stop()
        capture.wait(timeout=60)
    assert training.error is None, training.error
    assert capture.returncode == 0, capture.stderr.read().decode()[-2000:]
    assert shot.stat().st_size > 10_000
    assert "thermal frames" in capture_rows and "0 / 0" in capture_rows.replace("\t", " ")
    # offline: nothing but this server was asked for anything
    assert requests and all(u.startswith(handle.url) or u.startswith("data:") for u in requests), \
        [u for u in requests if not u.startswith(handle.url)]
    assert not errors, errors
