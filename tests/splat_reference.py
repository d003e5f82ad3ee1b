"""Dense pure-PyTorch reference of recon.splat.rasterization (float64, autograd backward).

Every Gaussian is evaluated at every pixel (no tiles, no bounding boxes), so it checks the
native tile rasterizer's culling as well as its maths. Same conventions as
recon/splat/rasterization.py: OpenCV world-to-camera viewmat, pixel centres at (x+0.5, y+0.5),
3DGS EWA projection with the clamped Jacobian and 0.3 px^2 blur, alpha = min(0.99, o exp(-q/2)),
skip alpha < 1/255, stop before T < 1e-4, expected depth sum(w z) / max(alpha, 1e-10).
"""
from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """q: (N,4) wxyz unit -> (N,3,3)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(-1, 3, 3)


def project(means, quats, log_scales, viewmat, fx, fy, cx, cy, width, height):
    """-> means2d (N,2), conics (N,3), depths (N,), cov2d (N,2,2)."""
    rot, trans = viewmat[:3, :3], viewmat[:3, 3]
    t = means @ rot.T + trans
    q = quats / quats.norm(dim=-1, keepdim=True)
    m = quat_to_rotmat(q) * log_scales.exp()[:, None, :]
    sigma_c = rot @ (m @ m.transpose(1, 2)) @ rot.T
    tx, ty, tz = t.unbind(-1)
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    u = (tx / tz).clamp(-(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x)
    v = (ty / tz).clamp(-(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(tz)
    jac = torch.stack([fx / tz, zero, -fx * u / tz, zero, fy / tz, -fy * v / tz], -1).reshape(-1, 2, 3)
    cov2d = jac @ sigma_c @ jac.transpose(1, 2) + 0.3 * torch.eye(2, dtype=means.dtype)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    conics = torch.stack([c / det, -b / det, a / det], -1)
    means2d = torch.stack([fx * tx / tz + cx, fy * ty / tz + cy], -1)
    return means2d, conics, tz, cov2d


def eval_sh(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """sh (N,K,C), dirs (N,3) -> (N,C) = max(sum_k Y_k sh_k + 0.5, 0)."""
    d = dirs / dirs.norm(dim=-1, keepdim=True)
    x, y, z = d.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
                  SH_C2[4] * (xx - yy)]
    if degree >= 3:
        basis += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                  SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                  SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    y_k = torch.stack(basis, -1)  # (N, nb)
    return ((y_k[:, :, None] * sh[:, : len(basis)]).sum(1) + 0.5).clamp_min(0.0)


def composite(means2d, conics, colors, opacities, depths, valid, width, height, pairs=False, pairs_move=True,
              among=None):
    """Dense front-to-back compositing -> image_sum (H,W,C), alpha (H,W), depth_sum (H,W), and with
    pairs the distortion (H,W) sum_{i<j} w_i w_j (z_i - z_j)^2, summed pair by pair ((H W N N) memory;
    pairs_move False: its z detached; among (N,): each pair weighted s_i s_j)."""
    dt = means2d.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dt), torch.arange(width, dtype=dt), indexing="ij")
    px, py = xs.reshape(-1, 1) + 0.5, ys.reshape(-1, 1) + 0.5
    dx, dy = px - means2d[:, 0], py - means2d[:, 1]  # (P, N)
    a, b, c = conics.unbind(-1)
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    alpha = (opacities * power.exp()).clamp(max=0.99)
    alpha = torch.where((alpha >= 1.0 / 255.0) & valid, alpha, torch.zeros_like(alpha))
    order = torch.argsort(depths.detach(), stable=True)
    alpha = alpha[:, order]
    keep = torch.cumprod(1 - alpha, dim=1) >= 1e-4  # stop before T would drop below 1e-4
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1]], 1), 1)
    w = alpha * trans
    image = (w @ colors[order]).reshape(height, width, -1)
    out = image, w.sum(1).reshape(height, width), (w @ depths[order]).reshape(height, width)
    if not pairs:
        return out
    z = depths[order] if pairs_move else depths[order].detach()
    upper = torch.triu(torch.ones(z.shape[0], z.shape[0], dtype=torch.bool, device=z.device), 1).to(z.dtype)
    if among is not None:
        s = among.to(z.dtype)[order]
        upper = upper * s[:, None] * s[None, :]
    spread = ((w[:, :, None] * w[:, None, :]) * (z[:, None] - z[None, :]) ** 2 * upper).sum((1, 2))
    return (*out, spread.reshape(height, width))


def render(means, quats, log_scales, opacities, features, viewmat, fx, fy, cx, cy, width, height,
           background=None, sh_degree=None, near_plane=0.01, cull_beside=None, distortion=False,
           distortion_moves=True, distortion_among=None):
    """Dense reference of rasterization(); returns dict of image, alpha, depth, means2d (and distortion)."""
    means2d, conics, depths, _ = project(means, quats, log_scales, viewmat, fx, fy, cx, cy, width, height)
    valid = (depths >= near_plane) & (opacities >= 1.0 / 255.0)
    if cull_beside is not None:
        m = cull_beside
        u, v = means2d.detach().unbind(-1)
        valid &= (u >= -m * width) & (u <= (1 + m) * width) & (v >= -m * height) & (v <= (1 + m) * height)
    # culled Gaussians must not leak NaN/inf from a camera-z near 0 into the sums or gradients
    means2d = torch.where(valid[:, None], means2d, torch.zeros_like(means2d))
    conics = torch.where(valid[:, None], conics, torch.ones_like(conics))
    if sh_degree is None:
        colors = features
    else:
        campos = -viewmat[:3, :3].T @ viewmat[:3, 3]
        colors = eval_sh(features, means - campos, sh_degree)
    image, alpha, depth_sum, *spread = composite(means2d, conics, colors, opacities, depths, valid, width, height,
                                                 pairs=distortion, pairs_move=distortion_moves,
                                                 among=distortion_among)
    if background is not None:
        image = image + (1 - alpha)[..., None] * background
    depth = depth_sum / alpha.clamp_min(1e-10)
    return {"image": image, "alpha": alpha, "depth": depth, "means2d": means2d,
            "distortion": spread[0] if spread else None}
