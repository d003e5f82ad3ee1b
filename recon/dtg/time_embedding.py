"""Time embedding e_t in R^D, defined for continuous t in [0, 1].

Two learned tables, as E-D3DGS's coarse and fine levels: half of the channels come from a
table with few rows (slow motion, temperature trends), half from one with more rows (fast
events). A lookup is linear interpolation between neighbouring rows, so any real t works.

The fine level is coarse-to-fine (E-D3DGS ``c2f``): it is read through a resampling of its
table to fewer rows early in training, growing to all rows by ``c2f_until``.

``temporal_smoothness`` is a real second difference over rows; E-D3DGS's published term pulls
every row toward the last one (research notes, ed3dgs_facts.md 2.4), which is not what it meant.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def lerp_rows(table: torch.Tensor, t: float, dim: int = 0) -> torch.Tensor:
    """Linear interpolation along `dim`: t in [0, 1] maps row 0 .. row R-1. table (R, D) -> (D,);
    with dim=1, (N, R, C) -> (N, C) (per-Gaussian trajectory knots)."""
    rows = table.shape[dim]
    x = min(max(float(t), 0.0), 1.0) * (rows - 1)
    i0 = min(int(x), rows - 1)
    i1 = min(i0 + 1, rows - 1)
    w = x - i0
    return torch.lerp(table.select(dim, i0), table.select(dim, i1), w)    # one autograd node, not three


def resample_rows(table: torch.Tensor, rows: int, dim: int = 0) -> torch.Tensor:
    """Linear resampling along `dim` to `rows` rows, endpoints kept (align_corners=True): (R, D) ->
    (rows, D); with dim=1, (N, R, C) -> (N, rows, C)."""
    if rows == table.shape[dim]:
        return table
    x = table.movedim(dim, -1)                        # (..., R)
    flat = x.reshape(-1, 1, x.shape[-1])
    out = F.interpolate(flat, size=rows, mode="linear", align_corners=True)
    return out.reshape(*x.shape[:-1], rows).movedim(-1, dim).contiguous()


class TimeEmbedding(nn.Module):
    def __init__(self, dim: int, rows_coarse: int, rows_fine: int, fine_start: float = 0.4,
                 c2f_until: float = 0.5):
        super().__init__()
        if dim % 2:
            raise ValueError(f"time embedding dim must be even, got {dim}")
        self.coarse = nn.Parameter(torch.zeros(rows_coarse, dim // 2))
        self.fine = nn.Parameter(torch.zeros(rows_fine, dim // 2))
        nn.init.normal_(self.coarse, std=0.01 / (dim ** 0.5))
        nn.init.normal_(self.fine, std=0.01 / (dim ** 0.5))
        self.fine_start = fine_start
        self.c2f_until = c2f_until

    @property
    def dim(self) -> int:
        return self.coarse.shape[1] * 2

    def fine_rows_at(self, progress: float) -> int:
        full = self.fine.shape[0]
        if self.c2f_until <= 0:
            return full
        a = min(max(progress / self.c2f_until, 0.0), 1.0)
        start = max(2, round(full * self.fine_start))
        return int(round(start + (full - start) * a))

    def forward(self, t: float, progress: float = 1.0) -> torch.Tensor:
        """e_t: (D,)"""
        fine = resample_rows(self.fine, self.fine_rows_at(progress))
        return torch.cat([lerp_rows(self.coarse, t), lerp_rows(fine, t)])

    @torch.no_grad()
    def extended(self, factor: int) -> dict[str, torch.Tensor]:
        """Tables for a time span `factor` times longer, rows at the same absolute times: the old
        rows are kept as they are (nothing learned is lost) and the new ones start as copies of
        the last row. -> {"coarse": (f(Rc-1)+1, D/2), "fine": (f(Rf-1)+1, D/2)}"""
        out = {}
        for name in ("coarse", "fine"):
            table = getattr(self, name)
            extra = (factor - 1) * (table.shape[0] - 1)
            out[name] = torch.cat([table, table[-1:].expand(extra, -1)])
        return out

    @torch.no_grad()
    def refined(self, factor: int) -> dict[str, torch.Tensor]:
        """Tables with `factor` times as many row intervals over the same span ((R-1)f+1 rows),
        interpolated from the old rows: past coarse-to-fine every lookup is unchanged, and the
        new rows can learn finer detail (a live capture whose time steps grew denser)."""
        return {name: resample_rows(getattr(self, name), (getattr(self, name).shape[0] - 1) * factor + 1)
                for name in ("coarse", "fine")}

    def temporal_smoothness(self) -> torch.Tensor:
        """Mean squared second difference over rows of both tables."""
        terms = []
        for table in (self.coarse, self.fine):
            if table.shape[0] >= 3:
                terms.append((table[2:] - 2 * table[1:-1] + table[:-2]).pow(2).mean())
        return torch.stack(terms).sum() if terms else self.coarse.sum() * 0
