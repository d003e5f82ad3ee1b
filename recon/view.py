"""`recon view RUN`: explore a trained run in the browser, any viewpoint and any time.

The model is loaded once (recon.render.load_run) into a `RenderService`, and the status server
(server.serve(..., renderer=service)) answers the viewer page's requests from it: RGB, kelvin and
depth at a pose, a time and a size, and the temperature over time of a picked surface point. The
page (server/viewer.html, at /view) does the orbit camera, colour maps, ranges, units and the
spot / box / line measurements from the kelvin it received; see docs/viewer.md.

    service = RenderService.from_run("runs/s1")
    out = service.render(c2w, t=0.4, width=320, height=240)   # {"rgb", "kelvin", "depth", "camera", ...}
    series = service.series(c2w, 0.4, 320, 240, x=160, y=120, n=24)

`LiveRenderService` is the same for a model still training (`recon run --serve`): a waiting
render is rendered by the training thread itself between two steps (`on_step(trainer)`; a flag
check when nobody asks), from the training model; a point-over-time series, or a render while
training does not step, is rendered by the server's worker from a copy of the model the training
thread hands over between two steps. Rendering is capped to LIVE_MAX_DUTY of the wall time (the
page waits the `pace_ms` each reply names) and draws no training randomness.

What the time series follows: the depth render (expected camera z of the composited surface) at
the picked pixel gives a 3D point P at the picked time t. The K = 8 Gaussians whose centres (as
deformed for the temperature render at t, routing by argmax, opacity >= 0.05) are nearest to P
are taken, with weights 1/(distance + 1e-6) normalised to sum 1. At each time s the point is
P(s) = sum_k w_k mean_k(s) + (P - sum_k w_k mean_k(t)), i.e. it moves with the weighted mean of
those Gaussians' deformed centres (translation only). P(s) is projected into the same camera; the
reading is the temperature render at time s at the pixel P(s) falls in (nearest pixel, no
interpolation), exactly what `recon render --time s` at that pose shows there. `visible` says
whether P(s) is in front (depth render at that pixel within 5 % + 1 cm of P(s)'s depth, alpha >= 0.4).
A pixel whose accumulated opacity is below 0.4 has no surface to pick (refused).
"""
from __future__ import annotations

import argparse
import os
import threading
import time
from pathlib import Path

import numpy as np
import torch

from recon.data import viewmat_from_c2w_opengl
from recon.render import inference_masks, load_run, render
from recon.scene import Camera
from rig.cli_format import positive_int

MIN_SIZE, MAX_WIDTH, MAX_HEIGHT = 8, 1280, 960
FOLLOW_K = 8
FOLLOW_MIN_OPACITY = 0.05
# While training, rendering takes at most this share of wall time. Each picture a second costs
# training ~2.8 % (the inline render plus the browser drawing it, when the browser shares the 2
# cores): at 0.08 the dragging page got 3.0 pictures/s and training kept 82 % of its speed, at 0.05
# 2.5/s and 86.5 %, at 0.03 1.7/s and 88 % (bench/results/viewer-duty, docs/viewer.md).
LIVE_MAX_DUTY = 0.04
LIVE_NICE = 10                # and the render worker thread runs at this nice level
MIN_SURFACE_ALPHA = 0.4       # a pixel this opaque has a surface to pick


def colour_maps() -> dict[str, list]:
    """The colour maps the page offers, as 256 x [r, g, b] (recon.viz's, plus grey)."""
    from recon import viz
    maps = {name: viz.colormap(name).tolist() for name in ("ironbow", "inferno")}
    maps["grey"] = [[i, i, i] for i in range(256)]
    return maps


def camera_entry(name: str, c2w, fx, fy, cx, cy, width, height) -> dict:
    return {"name": name, "c2w": np.asarray(c2w, np.float64).tolist(), "fx": float(fx), "fy": float(fy),
            "cx": float(cx), "cy": float(cy), "width": int(width), "height": int(height)}


def dataset_cameras(facts: dict, limit: int = 64) -> list[dict]:
    """The training cameras of the run's dataset (scene.json's "dataset"), if it is still there;
    else only scene.json's default camera."""
    cams = [camera_entry("default", **facts["camera"])]
    path = Path(facts.get("dataset", ""))
    if not (path / "transforms.json").exists():
        return cams
    try:
        from recon.data import load_dataset
        ds = load_dataset(path)
    except (OSError, ValueError):
        return cams
    frames = [f for m in ("rgb", "thermal") for f in ds.split(m, "train")]
    step = max(1, len(frames) // limit)
    for f in frames[::step][:limit]:
        cams.append(camera_entry(f"{f.modality} t={f.time:.3f}", f.c2w, f.fx, f.fy, f.cx, f.cy, f.width, f.height))
    return cams


class RenderService:
    """A model loaded once, rendered at any pose (OpenGL camera-to-world), time and size.

    Intrinsics follow the run's default camera (scene.json), scaled to the requested width (same
    horizontal field of view, square pixels, principal point kept centred vertically). One render
    at a time (a lock), so it is safe from several threads; the server adds the coalescing."""

    source = "run"

    def __init__(self, model, facts: dict, cameras: list[dict] | None = None, threads: int | None = None):
        self.model, self.facts = model, facts
        self.k_min, self.k_max = (float(v) for v in facts["thermal_range_k"])
        self.cameras = cameras or [camera_entry("default", **facts["camera"])]
        self.threads = threads
        self.default_size = (320, 240)
        self.lock = threading.Lock()
        self.renders = 0

    @classmethod
    def from_run(cls, run_dir: str | Path, threads: int | None = None) -> "RenderService":
        model, facts = load_run(Path(run_dir))
        model.eval()
        return cls(model, facts, dataset_cameras(facts), threads)

    # ------------------------------------------------------------------ what the page needs first
    def current_model(self):
        return self.model

    def time_range(self) -> list[float]:
        return [0.0, 1.0]

    def model_for_info(self):
        return self.current_model()

    def info(self) -> dict:
        model = self.model_for_info()
        return {"source": self.source, "ready": model is not None, "cameras": self.cameras, "time_range": self.time_range(),
                "thermal_range_k": [self.k_min, self.k_max],
                "modalities": list(model.cfg.modalities) if model is not None else [],
                "gaussians": int(model.num_gaussians) if model is not None else 0,
                "center": self.center(model), "size": list(self.default_size), "colour_maps": colour_maps()}

    @staticmethod
    def center(model) -> list[float] | None:
        """Median of the canonical Gaussian centres: where the page's orbit looks at first."""
        if model is None or model.num_gaussians == 0:
            return None
        return [float(v) for v in model.gaussians["means"].detach().median(0).values]

    # ------------------------------------------------------------------ rendering
    def camera(self, c2w, width: int, height: int) -> tuple[Camera, dict]:
        c2w = np.asarray(c2w, np.float64)
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise ValueError(f"expected a finite 4x4 camera-to-world matrix, got shape {c2w.shape}")
        base = self.facts["camera"]
        s = width / float(base["width"])
        intr = {"fx": float(base["fx"]) * s, "fy": float(base["fy"]) * s, "cx": float(base["cx"]) * s,
                "cy": float(base["cy"]) * s + (height - float(base["height"]) * s) / 2,
                "width": int(width), "height": int(height)}
        viewmat = torch.as_tensor(viewmat_from_c2w_opengl(c2w), dtype=torch.float32)
        return Camera(viewmat, intr["fx"], intr["fy"], intr["cx"], intr["cy"], intr["width"], intr["height"]), intr

    def _render(self, model, modality: str, t: float, camera: Camera):
        masks = inference_masks(model)
        return render(model, modality, t, camera, mask=None if masks is None else masks[modality],
                      threads=self.threads)

    def kelvin(self, u: torch.Tensor) -> np.ndarray:
        return (u * (self.k_max - self.k_min) + self.k_min).numpy().astype(np.float32)

    @torch.no_grad()
    def render(self, c2w, t: float, width: int, height: int) -> dict:
        """-> {"rgb": (H, W, 3) uint8 or None, "kelvin": (H, W) float32 or None, "depth", "alpha":
        (H, W) float32 (camera z, 0 where nothing; accumulated opacity), "camera": intrinsics used,
        "render_ms", "gaussians"}."""
        camera, intr = self.camera(c2w, width, height)
        with self.lock:
            model = self.current_model()
            if model is None:
                raise LookupError("no model yet")
            return self.render_model(model, camera, intr, t)

    @torch.no_grad()
    def render_model(self, model, camera: Camera, intr: dict, t: float, threads: int | None = -1) -> dict:
        """render() of a given model (threads -1: self.threads)."""
        t0 = time.perf_counter()
        saved, self.threads = self.threads, self.threads if threads == -1 else threads
        try:
            out = {"rgb": None, "kelvin": None, "depth": None}
            for m in model.cfg.modalities:
                image, raster, _ = self._render(model, m, float(t), camera)
                if m == "rgb":
                    out["rgb"] = (image.clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8)
                else:
                    out["kelvin"] = self.kelvin(image[..., 0])
                if out["depth"] is None or m == "thermal":   # the surface the temperature is read on
                    out["depth"] = raster.depth.numpy().astype(np.float32)
                    out["alpha"] = raster.alpha.numpy().astype(np.float32)
        finally:
            self.threads = saved
        self.renders += 1
        out.update(camera=intr, render_ms=round((time.perf_counter() - t0) * 1000, 2),
                   gaussians=int(model.num_gaussians))
        return out

    @torch.no_grad()
    def series(self, c2w, t: float, width: int, height: int, x: int, y: int, n: int = 24,
               times: list[float] | None = None) -> dict:
        """Temperature over time of the surface point under pixel (x, y) at time t (see the module
        docstring for exactly what is followed). -> {"point": [x, y, z] at t, "depth", "samples":
        [{"time", "x", "y", "kelvin" (None if outside the image), "visible", "point"}], ...}."""
        camera, intr = self.camera(c2w, width, height)
        if not (0 <= x < width and 0 <= y < height):
            raise ValueError(f"pixel ({x}, {y}) is outside the {width}x{height} view")
        lo, hi = self.time_range()
        times = list(np.linspace(lo, hi, n)) if times is None else times
        with self.lock:
            model = self.current_model()
            if model is None:
                raise LookupError("no model yet")
            modality = "thermal" if "thermal" in model.cfg.modalities else model.cfg.modalities[0]
            _, raster, g = self._render(model, modality, float(t), camera)
            alpha, z = float(raster.alpha[y, x]), float(raster.depth[y, x])
            if alpha < MIN_SURFACE_ALPHA or z <= 0:
                raise ValueError(f"no surface under pixel ({x}, {y}) at t={t:g} (opacity {alpha:.2f}); pick on the object")
            vm = camera.viewmat.double()
            r, tr = vm[:3, :3], vm[:3, 3]
            p_cam = torch.tensor([(x + 0.5 - intr["cx"]) / intr["fx"] * z, (y + 0.5 - intr["cy"]) / intr["fy"] * z, z],
                                 dtype=torch.float64)
            point = r.T @ (p_cam - tr)
            means = g["means"].double()
            ok = g["opacities"] >= FOLLOW_MIN_OPACITY
            index = torch.nonzero(ok).flatten()
            if len(index) == 0:
                raise ValueError("the model has no opaque Gaussian to follow")
            dist = (means[index] - point).norm(dim=1)
            near = torch.topk(dist, min(FOLLOW_K, len(index)), largest=False)
            idx = index[near.indices]
            w = 1.0 / (near.values + 1e-6)
            w = w / w.sum()
            offset = point - (w[:, None] * means[idx]).sum(0)
            samples = []
            for s in times:
                s = float(s)
                image, raster_s, g_s = self._render(model, modality, s, camera)
                p_s = (w[:, None] * g_s["means"].double()[idx]).sum(0) + offset
                pc = r @ p_s + tr
                entry = {"time": s, "point": [round(float(v), 6) for v in p_s], "x": None, "y": None,
                         "kelvin": None, "visible": False}
                if pc[2] > 1e-6:
                    px = int(np.floor(float(intr["fx"] * pc[0] / pc[2] + intr["cx"])))
                    py = int(np.floor(float(intr["fy"] * pc[1] / pc[2] + intr["cy"])))
                    if 0 <= px < width and 0 <= py < height:
                        k = self.kelvin(image[py, px, 0]) if modality == "thermal" else None
                        d, a = float(raster_s.depth[py, px]), float(raster_s.alpha[py, px])
                        entry.update(x=px, y=py, kelvin=None if k is None else float(k),
                                     visible=bool(a >= MIN_SURFACE_ALPHA and abs(d - float(pc[2])) <= 0.05 * float(pc[2]) + 0.01))
                samples.append(entry)
            self.renders += 1 + len(times)
        return {"time": float(t), "pixel": [x, y], "depth": z, "point": [float(v) for v in point],
                "followed": [int(i) for i in idx], "camera": intr, "c2w": np.asarray(c2w, float).tolist(),
                "modality": modality, "samples": samples}


class LiveRenderService(RenderService):
    """Renders the model being trained. `on_step(trainer)` (called by the training thread after
    each step; `chain(feed.on_step)` adds it to TrainingFeed's) renders the request waiting, if
    any (inline), and hands over a copy of the model when one was asked for and the copy held is
    older than `refresh_s`; otherwise it is a flag check. Renders from the copy (series; while
    training does not step) run in the server's worker thread at nice `nice` with `threads`
    rasterizer threads. max_duty caps rendering's share of wall time (pace(), pace_ms)."""

    source = "live"

    def __init__(self, refresh_s: float = 1.0, threads: int | None = 1, max_duty: float | None = LIVE_MAX_DUTY,
                 nice: int = LIVE_NICE, inline: bool = True):
        super().__init__(None, {"thermal_range_k": [0.0, 1.0], "camera": None}, [{}], threads)
        self.inline = inline              # renders run in the training thread between steps
        self._job, self._job_lock, self._stepped = None, threading.Lock(), 0.0
        self.inline_renders = 0
        self.nice, self._niced = nice, False
        self.refresh_s = refresh_s
        self.max_duty = max_duty          # at most this fraction of wall time spent rendering (None: no cap)
        self._render_end, self._render_s = 0.0, 0.0
        self._model, self._taken = None, 0.0
        self._want = threading.Event()
        self._fresh = threading.Event()
        self._times = [0.0, 1.0]
        self.snapshots = 0

    def on_step(self, trainer, *_) -> None:
        """After a training step, in the training thread: a flag check; or the render a request
        handed over (inline), rendered from the training model itself; or a copy of the model when
        one was asked for (series, renders while training does not step) or none was taken yet."""
        self._stepped = time.monotonic()
        if self._model is None or (self._want.is_set() and time.monotonic() - self._taken >= self.refresh_s):
            self._snapshot(trainer)
        with self._job_lock:
            job, self._job = self._job, None
        if job is not None:
            try:
                job["out"] = self.render_model(trainer.model, *job["args"], threads=None)
                self.inline_renders += 1
            except Exception as exc:       # handed to the request, training goes on
                job["error"] = exc
            job["done"].set()

    def _inline(self, camera, intr, t):
        """Render in the training thread between two steps; None if training does not step."""
        if not self.inline or time.monotonic() - self._stepped > 0.5:
            return None
        job = {"args": (camera, intr, t), "done": threading.Event()}
        with self._job_lock:
            self._job = job
        if not job["done"].wait(2.0):
            with self._job_lock:
                if self._job is job:       # not claimed: training stopped stepping meanwhile
                    self._job = None
                    return None
            job["done"].wait()             # claimed: it is being rendered
        if "error" in job:
            raise job["error"]
        return job["out"]

    def pace(self) -> None:
        """Called by the server's render worker before it takes the next request: with max_duty,
        waits so that rendering takes at most that share of the time (a drag's requests meanwhile
        coalesce into the newest)."""
        if self.nice and not self._niced:    # the render worker yields the CPU to training (Linux: per thread)
            self._niced = True
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self.nice)
            except (AttributeError, OSError):
                pass
        if self.max_duty:
            wait = self._render_end + self._render_s * (1 / self.max_duty - 1) - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, 1.0))

    def render(self, c2w, t: float, width: int, height: int) -> dict:
        camera, intr = self.camera(c2w, width, height) if self.facts["camera"] else (None, None)
        out = self._inline(camera, intr, t) if camera is not None else None
        if out is None:
            out = super().render(c2w, t, width, height)
        self._render_end, self._render_s = time.monotonic(), out["render_ms"] / 1000
        out["pace_ms"] = round(self._render_s * (1 / self.max_duty - 1) * 1000) if self.max_duty else 0
        return out

    def chain(self, on_step):
        """on_step(trainer, stats) that also calls self.on_step (for TrainingFeed.on_step)."""
        def both(trainer, stats):
            on_step(trainer, stats)
            self.on_step(trainer)
        return both

    def _snapshot(self, trainer) -> None:
        from recon.dtg.model import DTGModel
        scene = trainer.scene
        if self.facts["camera"] is None:
            views = [v for m in ("rgb", "thermal") for v in scene.train[m]]
            first = (scene.test["rgb"] or scene.test["thermal"] or views)[0].frame
            self.facts = {"thermal_range_k": [scene.k_min, scene.k_max],
                          "camera": camera_entry("default", first.c2w, first.fx, first.fy, first.cx, first.cy,
                                                 first.width, first.height)}
            self.facts["camera"].pop("name")
            self.k_min, self.k_max = scene.k_min, scene.k_max
            step = max(1, len(views) // 64)
            self.cameras = [camera_entry("default", **self.facts["camera"])] + [
                camera_entry(f"{v.frame.modality} t={v.time:.3f}", v.frame.c2w, v.frame.fx, v.frame.fy, v.frame.cx,
                             v.frame.cy, v.frame.width, v.frame.height) for v in views[::step][:64]]
        with torch.random.fork_rng(devices=[]), torch.no_grad():   # building a model draws no training randomness
            model = DTGModel.from_checkpoint(trainer.cfg.model, trainer.model.state_for_checkpoint())
        model.eval()
        self._times = [float(scene.times[0]), float(scene.times[-1])] if scene.times else [0.0, 1.0]
        self._model, self._taken = model, time.monotonic()
        self.snapshots += 1
        self._want.clear()
        self._fresh.set()

    def current_model(self):
        if self._model is None or time.monotonic() - self._taken >= self.refresh_s:
            self._want.set()                # the next training step hands over a fresh copy
        if self._model is None:
            self._fresh.wait(10.0)
        return self._model

    def time_range(self) -> list[float]:
        return list(self._times)

    def model_for_info(self):
        """The copy held, without waiting for one (None before training's first step)."""
        if self._model is None:
            self._want.set()
        return self._model

    def info(self) -> dict:
        out = super().info()
        out["snapshot_age_s"] = round(time.monotonic() - self._taken, 2) if self._model is not None else None
        return out


# ---------------------------------------------------------------------- `recon view`
def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 320x240, got {text!r}") from None
    if not (MIN_SIZE <= w <= MAX_WIDTH and MIN_SIZE <= h <= MAX_HEIGHT):
        raise argparse.ArgumentTypeError(f"size must be within {MIN_SIZE}x{MIN_SIZE}..{MAX_WIDTH}x{MAX_HEIGHT}, got {text}")
    return w, h


def view_command(args) -> int:
    import server
    run_dir = Path(args.run)
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in 0..65535, got {args.port}")
    if args.threads:
        torch.set_num_threads(args.threads)
    service = RenderService.from_run(run_dir, threads=args.threads)
    service.default_size = args.size
    try:
        handle = server.serve(args.host, args.port, run_dir=run_dir, renderer=service)
    except OSError as exc:
        raise ValueError(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc}") from None
    print(f"viewer: {handle.url}view  ({service.model.num_gaussians} Gaussians; status page {handle.url}; "
          f"Ctrl-C to stop)", flush=True)
    try:
        threading.Event().wait(args.seconds) if args.seconds else threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        handle.stop()
    return 0


def register(sub) -> None:
    from server.app import DEFAULT_HOST, DEFAULT_PORT
    p = sub.add_parser(
        "view", help="explore a trained run in the browser: any pose, any time, temperature measurements",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Serve a viewer page for a trained run (its latest checkpoint, loaded once): orbit, pan "
                    "and zoom from the training cameras, a time slider, RGB and temperature side by side, "
                    "colour map and range in deg C / K / deg F, spot, box, line and point-over-time "
                    "measurements, PNG and CSV export. Renders come from the model in this process.",
        epilog="examples:\n"
               "  recon view runs/s1                        # http://127.0.0.1:8765/view\n"
               "  recon view runs/s1 --host 0.0.0.0 --port 9000   # reachable from the LAN\n"
               "  recon view runs/s1 --size 640x480 --threads 2\n"
               "mouse: left drag orbit, right drag (or shift+drag) pan, wheel zoom; keys: W/A/S/D move, Q/E down/up,\n"
               "arrows orbit, R back to the camera, [ ] previous/next training camera, space play, , . step time.\n"
               "see docs/viewer.md")
    p.add_argument("run", metavar="RUN", help="a `recon run` output folder")
    p.add_argument("--host", default=DEFAULT_HOST, help="address to bind (0.0.0.0 = every interface)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port (0 = any free)")
    p.add_argument("--size", type=parse_size, default=(320, 240), help="the page's initial render size, WIDTHxHEIGHT")
    p.add_argument("--threads", type=positive_int, help="CPU threads for rendering (default: all)")
    p.add_argument("--seconds", type=float, default=None, help=argparse.SUPPRESS)   # tests: stop after this long
    p.set_defaults(func=view_command)
