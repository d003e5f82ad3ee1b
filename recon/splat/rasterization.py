"""`rasterization()`: render N world-space 3D Gaussians through a pinhole camera, differentiably.

Conventions (identical in the dense reference of the tests):
- camera: `viewmat` is world-to-camera in OpenCV axes (x right, y down, z forward);
  a pixel (x, y) has its centre at (x + 0.5, y + 0.5) in the units of fx, fy, cx, cy (as gsplat
  and nerfstudio; cx = width/2 is a centred principal point).
- math as 3DGS: EWA projection (the Jacobian's tx/tz, ty/tz clamped to the image plus 0.3
  tan(fov/2) per side), +0.3 px^2 on the 2D covariance diagonal, alpha = min(0.99, o exp(-q/2)),
  contributions with alpha < 1/255 skipped, front to back by camera z of the mean, and a pixel
  stops before the Gaussian that would take its transmittance below 1e-4.
- footprint: opacity-aware, i.e. exactly where alpha can reach 1/255 (q <= 2 ln(255 o)), so the
  result never depends on tile binning; Gaussians with o < 1/255 or camera z < near_plane are
  culled, and with `cull_beside` = m those whose centre projects more than m x the (full) view's
  width or height beyond its edges: the clamped Jacobian keeps such a centre's small depth, so a
  long Gaussian far to the side can cover the whole view (3DGS culls on depth only).
- depth: expected camera z of the composited surface, sum(w_i z_i) / max(alpha, 1e-10); where
  alpha is 0 it is 0.
- distortion (asked for): sum over pairs i < j of w_i w_j (z_i - z_j)^2 per pixel, the squared form
  of Mip-NeRF 360's and 2DGS's distortion loss on the Gaussians' camera z; it is 0 where one
  surface holds a pixel's weight and grows with weight spread in depth along the ray.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from recon.splat._functions import Project, Rasterize

DEPTH_EPS = 1e-10
MAX_TILE_PAIRS = 1 << 28  # 1 GiB of tile lists; beyond this a clear MemoryError
NEAR_PLANE = 0.01         # camera z below which a Gaussian is culled

@dataclass
class RenderOutput:
    image: torch.Tensor    # (H, W, C) composited + (1 - alpha) * background
    alpha: torch.Tensor    # (H, W) accumulated opacity, 1 - final transmittance
    depth: torch.Tensor    # (H, W) expected camera z, sum(w z) / max(alpha, 1e-10)
    radii: torch.Tensor    # (N,) int32 pixel radius of the opacity-aware footprint; 0 = culled
    visible: torch.Tensor  # (N,) bool, radii > 0
    means2d: torch.Tensor  # (N, 2) projected pixel-space means; .grad holds dL/dmeans2d after backward
    distortion: torch.Tensor | None = None  # (H, W) sum_{i<j} w_i w_j (z_i - z_j)^2, when asked for


def _shape(x: torch.Tensor) -> str:
    return "(" + ",".join(str(d) for d in x.shape) + ")"


def _check(name: str, x, shape: tuple, dtypes=(torch.float32,)) -> None:
    """Raise ValueError naming `name` unless x is a finite CPU tensor of `shape` (-1 = any)."""
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.device.type != "cpu":
        raise ValueError(f"{name} is on {x.device}; recon.splat renders on the CPU only (move it with .cpu())")
    if x.dtype not in dtypes:
        raise ValueError(f"{name} must have dtype {' or '.join(str(d) for d in dtypes)}, got {x.dtype} with shape {_shape(x)}")
    want = "(" + ",".join("N" if d == -1 else str(d) for d in shape) + ")"
    if x.dim() != len(shape) or any(d != -1 and s != d for s, d in zip(x.shape, shape)):
        raise ValueError(f"{name} must have shape {want}, got {_shape(x)}")
    # a sum is finite when every value is (17x cheaper than isfinite().all() on 12k Gaussians);
    # only a non-finite sum (or a finite one that overflowed) pays for the exact test
    if x.numel() and not math.isfinite(x.detach().sum().item()) and not bool(torch.isfinite(x).all()):
        raise ValueError(f"{name} with shape {_shape(x)} contains non-finite values")


def _check_camera(fx, fy, cx, cy, width, height, near_plane) -> None:
    for name, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy), ("near_plane", near_plane)):
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"{name} must be a finite number, got {v!r}")
    if fx <= 0 or fy <= 0:
        raise ValueError(f"fx and fy must be > 0, got fx={fx}, fy={fy}")
    if near_plane <= 0:
        raise ValueError(f"near_plane must be > 0, got {near_plane}")
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")


def intrinsics(fx, fy, cx, cy, width, height, near_plane=NEAR_PLANE, window=None, cull_beside=None) -> tuple:
    """Checked camera values -> the projection's intr tuple (fx, fy, cx, cy, width, height,
    near_plane, window, beside); window (x0, y0, full_width, full_height), None: the whole view;
    cull_beside None: off (beside -1)."""
    _check_camera(fx, fy, cx, cy, width, height, near_plane)
    window = (0, 0, width, height) if window is None else tuple(int(v) for v in window)
    if len(window) != 4 or min(window[:2]) < 0 or window[0] + width > window[2] or window[1] + height > window[3]:
        raise ValueError(f"window {window} must be (x0, y0, full_width, full_height) holding the {width}x{height} image")
    beside = -1.0 if cull_beside is None else check_cull_beside(cull_beside)
    return (float(fx), float(fy), float(cx), float(cy), width, height, float(near_plane), window, beside)


def check_cull_beside(value) -> float:
    """A `cull_beside` margin as float; ValueError unless it is a finite number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
        raise ValueError(f"cull_beside must be None or a finite number >= 0, got {value!r}")
    return float(value)


def _check_features(features, sh_degree, n: int) -> None:
    """features (N,C) used as colours, or SH coefficients (N,K>=(sh_degree+1)^2,C)."""
    if sh_degree is None:
        _check("features", features, (n, -1))
        if features.shape[1] < 1:
            raise ValueError(f"features must have at least 1 channel, got {_shape(features)}")
        return
    if not isinstance(sh_degree, int) or isinstance(sh_degree, bool) or not 0 <= sh_degree <= 3:
        raise ValueError(f"sh_degree must be None or an int in 0..3, got {sh_degree!r}")
    need = (sh_degree + 1) ** 2
    if isinstance(features, torch.Tensor) and features.dim() == 3:
        _check("features", features, (n, -1, -1))
    if not isinstance(features, torch.Tensor) or features.dim() != 3 or features.shape[1] < need or features.shape[2] < 1:
        raise ValueError(
            f"features as SH of degree {sh_degree} must have shape (N,K>={need},C>=1), got "
            + (_shape(features) if isinstance(features, torch.Tensor) else type(features).__name__)
        )


def project(means, quats, log_scales, opacities, features, viewmat, intr: tuple, sh_degree, threads: int):
    """Checked inputs -> means2d (N,2), conics (N,3), depths (N,), radii (N,), colors (N,C).

    One native pass (Project): colors are features as is, or SH evaluated for the direction
    camera -> Gaussian. intr: `intrinsics()`'s tuple.
    """
    sh = None if sh_degree is None else features.contiguous()
    means2d, conics, depths, radii, colors = Project.apply(
        means, quats, log_scales, opacities, sh, viewmat, intr, sh_degree or 0, threads
    )
    return means2d, conics, depths, radii, features if sh is None else colors


def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    viewmat: torch.Tensor,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    sh_degree: int | None = None,
    near_plane: float = NEAR_PLANE,
    threads: int | None = None,
    max_tile_pairs: int = MAX_TILE_PAIRS,
    window: tuple[int, int, int, int] | None = None,
    cull_beside: float | None = None,
    distortion: bool = False,
    distortion_moves: bool = True,
    distortion_among: torch.Tensor | None = None,
) -> RenderOutput:
    """Render Gaussians to (H,W,C); differentiable in every tensor input (and viewmat).

    means (N,3) world; quats (N,4) wxyz, any non-zero norm (normalised inside); log_scales (N,3);
    opacities (N,) in [0,1]; features (N,C) used as colours, or SH coefficients (N,K,C) with
    K >= (sh_degree+1)^2 when sh_degree is given (colour = max(SH(dir) + 0.5, 0), 3DGS).
    viewmat (4,4) world-to-camera, OpenCV axes. background (C,) or None (zeros).
    threads defaults to torch.get_num_threads(). All tensors float32 on the CPU.
    window (x0, y0, full_width, full_height): the image is the window at (x0, y0) of a larger view
    (PinholeCamera.crop); it then renders exactly that part of the larger view's render (3DGS's
    clamp of the projection's Jacobian follows the larger view's edges). None: the whole view.
    cull_beside m: Gaussians whose centre (in front of the camera) projects more than m x the
    whole view's width (height) beyond its edges are culled, as the near plane culls (a window
    culls as its whole view does); None: off.
    distortion: also return out.distortion (H, W), differentiable (two more channels to composite);
    distortion_moves False: its gradient reaches the Gaussians through their blend weights only,
    not through their depths (it can make a Gaussian fainter, not pull it along the ray).
    distortion_among (N,) >= 0, constant: the pairs counted are weighted s_i s_j, so a 0/1 mask
    counts the pairs among the Gaussians it marks only (one more channel); None: all pairs.
    """
    _check("means", means, (-1, 3))
    n = means.shape[0]
    _check("quats", quats, (n, 4))
    _check("log_scales", log_scales, (n, 3))
    _check("opacities", opacities, (n,))
    _check("viewmat", viewmat, (4, 4), (torch.float32, torch.float64))
    if distortion_among is not None:
        if not distortion:
            raise ValueError("distortion_among is given but distortion is False")
        _check("distortion_among", distortion_among, (n,), (torch.float32, torch.float64, torch.bool))
    intr = intrinsics(fx, fy, cx, cy, width, height, near_plane, window, cull_beside)
    threads = torch.get_num_threads() if threads is None else int(threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    viewmat = viewmat.float()
    _check_features(features, sh_degree, n)
    channels = features.shape[-1]
    if background is not None:
        _check("background", background, (channels,), (torch.float32, torch.float64))
    means2d, conics, depths, radii, colors = project(means, quats, log_scales, opacities, features, viewmat, intr,
                                                     sh_degree, threads)
    if means2d.requires_grad:
        means2d.retain_grad()
    if distortion:
        moments = depth_moments(depths if distortion_moves else depths.detach(), radii, distortion_among)
        colors = torch.cat([colors, moments], 1)
    image, alpha, depth_sum = Rasterize.apply(
        means2d, conics, colors, opacities, depths, radii, width, height, max_tile_pairs, threads
    )
    spread = None
    if distortion:
        extra = image[..., channels:]
        image = image[..., :channels]
        # with W = sum w, M1 = sum w m, M2 = sum w m^2: sum_{i<j} w_i w_j (m_i - m_j)^2 = W M2 - M1^2
        # (weighted by s: S = sum w s, M1 = sum w s m, M2 = sum w s m^2)
        total, m1, m2 = (alpha, extra[..., 0], extra[..., 1]) if distortion_among is None else extra.unbind(-1)
        spread = (total * m2 - m1 * m1).clamp_min(0.0)
    if background is not None:
        image = image + (1.0 - alpha)[..., None] * background.float()
    depth = depth_sum / alpha.clamp_min(DEPTH_EPS)
    return RenderOutput(image=image, alpha=alpha, depth=depth, radii=radii, visible=radii > 0, means2d=means2d,
                        distortion=spread)


def depth_moments(depths: torch.Tensor, radii: torch.Tensor, among: torch.Tensor | None = None) -> torch.Tensor:
    """(N, 2) channels m, m^2 with m = camera z less the drawn Gaussians' median (detached): the
    distortion is the same for any shift, and a centred m keeps W M2 - M1^2 from cancelling in float32.
    among (N,) >= 0: (N, 3) channels s, s m, s m^2 with s = among (detached), for S M2 - M1^2."""
    drawn = depths.detach()[radii > 0]
    m = depths - (drawn.median() if drawn.numel() else 0.0)
    if among is None:
        return torch.stack([m, m * m], 1)
    s = among.detach().to(m.dtype)
    return torch.stack([s, s * m, s * m * m], 1)
