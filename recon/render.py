"""Render a DTG model: one modality, one camera, one instant."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from recon.dtg import routing
from recon.train.checkpoint import read_checkpoint
from recon.dtg.model import DTGModel
from recon.scene import Camera
from recon.splat import rasterization
from recon.splat.rasterization import intrinsics, project
from recon.data import viewmat_from_c2w_opengl


def inference_masks(model: DTGModel) -> dict[str, torch.Tensor] | None:
    """Deterministic routing masks (argmax roles), or None when routing is off."""
    if "route_logits" not in model.gaussians:
        return None
    roles = routing.hard_roles(model.gaussians["route_logits"].detach())
    return routing.masks(torch.nn.functional.one_hot(roles, 3).float())


def pixel_boxes(camera: Camera, means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor,
                opacities: torch.Tensor, threads: int | None = None, cull_beside: float | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where Gaussians (means (N, 3), quats, log_scales, opacities (N,)) can draw in camera: the
    rasterizer's own opacity-aware footprint plus a pixel, as boxes lo (N, 2), hi (N, 2) in pixels,
    and drawn (N,) bool (what its projection culls draws nothing; cull_beside: the rasterizer's)."""
    intr = intrinsics(*camera.args()[1:], window=camera.window, cull_beside=cull_beside)
    means2d, _, _, radii, _ = project(means, quats, log_scales, opacities, torch.ones(means.shape[0], 1),
                                      camera.viewmat.float(), intr, None,
                                      torch.get_num_threads() if threads is None else threads)
    r = (radii + 1).float()[:, None]
    return means2d - r, means2d + r, radii > 0


def in_view(camera: Camera, threads: int | None = None, cull_beside: float | None = None):
    """geometry {means (N,3), quats, log_scales}, margin -> (R,) indices of the Gaussians the
    rasterizer may draw in this camera (its projection's culling at full opacity, the widest
    footprint: a superset of what any opacity draws; cull_beside: the render's off-view cull);
    with a margin (a fraction, see `PinholeCamera.widened`) in the camera widened by it instead,
    and without the cull (geometry that a network may still move: any Gaussian reaching into it)."""
    def rows(geo: dict[str, torch.Tensor], margin: float | None = None) -> torch.Tensor:
        cam = camera if margin is None else camera.widened(margin)
        ones = torch.ones(geo["means"].shape[0])
        cull = cull_beside if margin is None else None
        drawn = pixel_boxes(cam, geo["means"], geo["quats"], geo["log_scales"], ones, threads, cull)[2]
        return torch.nonzero(drawn).view(-1)
    return rows


def render(model: DTGModel, modality: str, t: float, camera: Camera, progress: float = 1.0,
           sh_degree: int | None = None, mask: torch.Tensor | None = None,
           rgb_geometry: dict[str, torch.Tensor] | None = None, background: torch.Tensor | None = None,
           threads: int | None = None, frozen: torch.Tensor | None = None, distortion: bool = False,
           distortion_moves: bool = True, distortion_among: torch.Tensor | None = None):
    """-> (image (H, W, C) over the background, rasterizer output, the Gaussians used).

    sh_degree: active SH degree (None: all the model has); background (C,): None = the learned one;
    threads: rasterizer threads (None: torch's); frozen (N,) bool: Gaussians this render may not
    train (their parameters are seen detached); distortion: the output's distortion too
    (distortion_moves, distortion_among (N,): the rasterizer's)."""
    g = model.render_inputs(modality, t, progress, mask=mask, rgb_geometry=rgb_geometry,
                            in_view=in_view(camera, threads, model.cfg.cull_off_view))
    if frozen is not None:
        g = {**g, **{k: torch.where(frozen.view(-1, *[1] * (g[k].dim() - 1)), g[k].detach(), g[k])
                     for k in ("means", "quats", "log_scales", "opacities", "features")}}
    image, out = draw(model, modality, g, camera, sh_degree, background, threads, distortion, distortion_moves,
                      distortion_among)
    return image, out, g


def draw(model: DTGModel, modality: str, g: dict[str, torch.Tensor], camera: Camera, sh_degree: int | None = None,
         background: torch.Tensor | None = None, threads: int | None = None, distortion: bool = False,
         distortion_moves: bool = True, distortion_among: torch.Tensor | None = None):
    """Rasterize a modality's render inputs g (DTGModel.render_inputs) in camera over the
    background (None: the learned one) -> (image (H, W, C), rasterizer output). Gaussians whose
    centre is far beside the view are culled when the model says so (ModelConfig.cull_off_view:
    the rasterizer's `cull_beside`)."""
    feats = g["features"]
    degree = int(round(feats.shape[1] ** 0.5)) - 1 if sh_degree is None else sh_degree
    out = rasterization(g["means"], g["quats"], g["log_scales"], g["opacities"],
                        feats[:, : (degree + 1) ** 2], camera.viewmat, camera.fx, camera.fy,
                        camera.cx, camera.cy, camera.width, camera.height, sh_degree=degree, threads=threads,
                        window=camera.window, cull_beside=model.cfg.cull_off_view, distortion=distortion,
                        distortion_moves=distortion_moves, distortion_among=distortion_among)
    bg = model.backgrounds[modality] if background is None else background
    return out.image + (1 - out.alpha)[..., None] * bg, out


@torch.no_grad()
def render_frame(model: DTGModel, modality: str, t: float, camera: Camera) -> torch.Tensor:
    """Inference render (routing by argmax). -> (H, W, C): RGB in [0, 1] or normalised temperature."""
    masks = inference_masks(model)
    image, _, _ = render(model, modality, t, camera, mask=None if masks is None else masks[modality])
    return image


@torch.no_grad()
def render_frame_layers(model: DTGModel, modality: str, t: float, camera: Camera):
    """Inference render with its geometry: (image (H, W, C), expected depth (H, W), alpha (H, W))."""
    masks = inference_masks(model)
    image, out, _ = render(model, modality, t, camera, mask=None if masks is None else masks[modality])
    return image, out.depth, out.alpha


# ---------------------------------------------------------------------- `recon render`
def load_run(run_dir: Path) -> tuple[DTGModel, dict]:
    """The model of a run (its latest checkpoint) and the run's scene facts (scene.json)."""
    from recon.config import config_from_dict

    ckpt = run_dir / "checkpoints" / "latest.pt"
    facts_path = run_dir / "scene.json"
    for path in (ckpt.parent, facts_path):
        if not path.exists():
            raise ValueError(f"{path}: missing; is {run_dir} a `recon run` folder?")
    state, _ = read_checkpoint(ckpt, log=lambda m: print(m, file=sys.stderr))
    cfg = config_from_dict(state["config"])
    return DTGModel.from_checkpoint(cfg.model, state["model"]), json.loads(facts_path.read_text())


def camera_from_args(args, facts: dict) -> Camera:
    cam = dict(facts["camera"])
    for key in ("fx", "fy", "cx", "cy", "width", "height"):
        if getattr(args, key) is not None:
            cam[key] = getattr(args, key)
    if args.pose:
        literal = args.pose.lstrip().startswith("[")       # a matrix, not a file name (too long for one)
        try:
            text = args.pose if literal else Path(args.pose).read_text()
            c2w = np.asarray(json.loads(text), dtype=np.float64)
        except ValueError as exc:
            raise ValueError(f"--pose {args.pose[:60]!r}: not a JSON 4x4 matrix ({exc})") from None
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise ValueError(f"--pose: expected a 4x4 camera-to-world matrix (OpenGL axes), got shape {c2w.shape}")
        cam["c2w"] = c2w.tolist()
    viewmat = torch.as_tensor(viewmat_from_c2w_opengl(np.asarray(cam["c2w"])), dtype=torch.float32)
    return Camera(viewmat, float(cam["fx"]), float(cam["fy"]), float(cam["cx"]), float(cam["cy"]),
                  int(cam["width"]), int(cam["height"]))


def render_command(args) -> int:
    from recon import viz
    from recon.eval.renders import encode_render

    model, facts = load_run(Path(args.run))
    camera = camera_from_args(args, facts)
    k_min, k_max = facts["thermal_range_k"]
    prefix = Path(args.out)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    for m in model.cfg.modalities:
        img = render_frame(model, m, args.time, camera)
        if m == "rgb":
            Image.fromarray(encode_render(img.numpy(), "rgb", None)).save(f"{prefix}_rgb.png")
        else:
            kelvin = (img[..., 0] * (k_max - k_min) + k_min).numpy()
            Image.fromarray(encode_render(kelvin, "thermal", facts["thermal_scale_k"])).save(f"{prefix}_thermal.png")
            Image.fromarray(viz.thermal_image(kelvin, k_min, k_max)).save(f"{prefix}_thermal_celsius.png")
            print(f"temperature at t={args.time:g}: min {kelvin.min() - 273.15:.1f} C, "
                  f"max {kelvin.max() - 273.15:.1f} C")
    print(f"wrote {prefix}_*.png")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "render", help="render RGB and temperature of a trained run at any time and pose",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Render a trained run (its latest checkpoint) at time t from a camera. Writes "
                    "OUT_rgb.png, OUT_thermal.png (16-bit counts in the dataset's thermal_scale_k) and "
                    "OUT_thermal_celsius.png (colour map with a colourbar in deg C).",
        epilog="examples:\n"
               "  recon render runs/dtg --time 0.5 --out renders/mid       # the run's first test camera\n"
               "  recon render runs/dtg --time 0.25 --pose pose.json --out renders/novel\n"
               "pose.json holds a 4x4 camera-to-world matrix in OpenGL axes, as transforms.json.")
    p.add_argument("run", metavar="RUN", help="a `recon run` output folder")
    p.add_argument("--time", type=float, default=0.5, help="normalised time in [0, 1] (default 0.5)")
    p.add_argument("--pose", help="4x4 camera-to-world (OpenGL), a JSON file or literal (default: first test camera)")
    for key, typ in (("fx", float), ("fy", float), ("cx", float), ("cy", float), ("width", int), ("height", int)):
        p.add_argument(f"--{key}", type=typ, help=f"intrinsic {key} (default: the first test camera's)")
    p.add_argument("--out", default="render", help="output prefix (default: ./render)")
    p.set_defaults(func=render_command)
