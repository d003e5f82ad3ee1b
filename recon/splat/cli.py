"""`recon splat-render`: render a static 3DGS PLY at the pose of one frame of a prepared dataset."""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from recon.splat.cameras import PinholeCamera, viewmat_from_c2w_opengl
from recon.splat.ply import read_gaussians_ply
from recon.splat.rasterization import check_cull_beside, rasterization

EPILOG = """examples:
  recon splat-render point_cloud.ply --transforms data/scene/transforms.json --frame 0 --out f0.png
  recon splat-render model.ply --transforms data/scene/transforms.json --frame 12 --out f12.png --background 1,1,1

The pose is frame K's transform_matrix (camera-to-world, OpenGL axes, as nerfstudio); the
intrinsics are the frame's fl_x fl_y cx cy w h, else the file's top-level ones. Lens distortion
(k1 k2 p1 p2) is ignored: the render is pinhole.
"""


def frame_camera(transforms_path: Path, index: int) -> PinholeCamera:
    """Frame `index` of a transforms.json (see FORMATS.md); errors name the file and the key."""
    try:
        meta = json.loads(transforms_path.read_text())
    except OSError as e:
        raise ValueError(f"{transforms_path}: cannot read: {e.strerror or e}") from e
    except json.JSONDecodeError as e:
        raise ValueError(f"{transforms_path}: not valid JSON: {e}") from e
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list) or not frames:
        raise ValueError(f"{transforms_path}: no 'frames' list")
    if not -len(frames) <= index < len(frames):
        raise ValueError(f"{transforms_path}: --frame {index} out of range (the file has {len(frames)} frames)")
    frame = frames[index]

    def value(key: str) -> float:
        v = frame.get(key, meta.get(key))
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise ValueError(f"{transforms_path}: frame {index} has no numeric '{key}' (nor does the file)")
        return float(v)

    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{transforms_path}: frame {index} has no numeric 4x4 'transform_matrix'") from None
    if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
        raise ValueError(f"{transforms_path}: frame {index} 'transform_matrix' must be a finite 4x4, got shape {c2w.shape}")
    width, height = value("w"), value("h")
    if width < 1 or height < 1 or width != int(width) or height != int(height):
        raise ValueError(f"{transforms_path}: frame {index} image size w={width}, h={height} is not positive integers")
    return PinholeCamera(viewmat_from_c2w_opengl(c2w), value("fl_x"), value("fl_y"), value("cx"), value("cy"),
                       int(width), int(height))


def parse_background(text: str) -> torch.Tensor:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"--background must be R,G,B with values in [0,1], got {text!r}")
    return torch.tensor(values, dtype=torch.float32)


def parse_cull_beside(text: str) -> float | None:
    """argparse type of --cull-beside: 'off' or what rasterization's check_cull_beside accepts."""
    if text == "off":
        return None
    try:
        return check_cull_beside(float(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--cull-beside must be a number >= 0 or 'off', got {text!r}") from None


def render_ply(ply_path: Path, camera: PinholeCamera, background: torch.Tensor,
               cull_beside: float | None = 1.0) -> np.ndarray:
    """-> (H,W,3) uint8 render of a 3DGS PLY (opacity sigmoid, SH degree from the file)."""
    g = read_gaussians_ply(ply_path)
    with torch.no_grad():
        out = rasterization(
            torch.from_numpy(g.means), torch.from_numpy(g.quats), torch.from_numpy(g.log_scales),
            torch.sigmoid(torch.from_numpy(g.opacity_logits)), torch.from_numpy(np.ascontiguousarray(g.sh)),
            *camera.args(), background=background, sh_degree=g.sh_degree, cull_beside=cull_beside,
        )
    return (out.image.clamp(0, 1) * 255).round().to(torch.uint8).numpy()


def run(args: argparse.Namespace) -> int:
    from PIL import Image

    camera = frame_camera(args.transforms, args.frame)
    start = time.perf_counter()
    image = render_ply(args.model, camera, args.background, args.cull_beside)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(args.out)
    ms = 1e3 * (time.perf_counter() - start)
    print(f"rendered {args.model} at frame {args.frame} ({camera.width}x{camera.height}) in {ms:.0f} ms -> {args.out}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "splat-render",
        help="render a static 3DGS PLY at the pose of one dataset frame",
        description="Render a static 3D Gaussian splatting model (standard 3DGS PLY) with the native CPU "
        "rasterizer at the pose and intrinsics of frame K of a prepared dataset's transforms.json.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("model", type=Path, metavar="MODEL.ply", help="3DGS PLY (x,y,z, f_dc_*, f_rest_*, opacity, scale_*, rot_*)")
    p.add_argument("--transforms", type=Path, required=True, metavar="DIR/transforms.json", help="prepared dataset's transforms.json")
    p.add_argument("--frame", type=int, default=0, metavar="K", help="index into its 'frames' list (default: %(default)s)")
    p.add_argument("--out", type=Path, required=True, metavar="OUT.png", help="output image (PNG, 8-bit RGB)")
    p.add_argument("--background", type=parse_background, default=torch.zeros(3), metavar="R,G,B",
                   help="background colour, values in [0,1] (default: 0,0,0 = black)")
    p.add_argument("--cull-beside", type=parse_cull_beside, default=1.0, metavar="M|off",
                   help="leave out Gaussians whose centre projects more than M view widths (heights) beyond "
                   "the view's edges, as `recon` draws its models (ModelConfig.cull_off_view); 'off' draws "
                   "them as other 3DGS viewers do (default: %(default)s)")
    p.set_defaults(func=_guarded)


def _guarded(args: argparse.Namespace) -> int:
    """Bad files and arguments print one clear line and exit 2 instead of a traceback."""
    try:
        return run(args)
    except ValueError as e:
        print(f"recon splat-render: error: {e}")
        return 2
