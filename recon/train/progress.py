"""The one-line progress report of a run (as tqdm's, without the dependency)."""
from __future__ import annotations


def progress_line(p: float, iteration: int, its: float, losses: dict[str, float], psnrs: dict[str, float],
                  roles: dict[str, int], eta_s: float) -> str:
    """`[####      ]  40.0% it 1200 | 25.1 it/s | loss rgb 0.0412 | PSNR(held-out) rgb 24.10 | ...`
    losses: {"loss_rgb": ...}; psnrs: per modality; roles: Gaussians per routing role."""
    ls = " ".join(f"{k[5:]} {v:.4f}" for k, v in losses.items())
    ps = " ".join(f"{m} {v:.2f}" for m, v in psnrs.items())
    rs = " ".join(f"{k} {v}" for k, v in roles.items())
    eta = int(eta_s)
    return (f"[{'#' * int(20 * p):<20}] {100 * p:5.1f}% it {iteration} | {its:5.1f} it/s | loss {ls} | "
            f"PSNR(held-out) {ps or '-'} | Gaussians {rs} | ETA {eta // 60}:{eta % 60:02d}")
