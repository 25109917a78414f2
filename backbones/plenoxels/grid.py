"""Sparse voxel grid storage and trilinear interpolation (pure functions).

A grid of resolution ``[X, Y, Z]`` has its grid points on the *vertices* spanning the scene box:
point ``i`` along x sits at ``lo.x + i * (hi.x - lo.x) / (X - 1)``, so every point inside the box
has grid coordinates in ``[0, X-1]`` and resampling to another resolution never extrapolates.
Only occupied points are stored: ``index [X, Y, Z]`` int32 maps a point to its row in the value
tables (``density [M]``, ``sh [M, K, 3]``) or ``-1``. Empty points read as 0 (density and SH), so
memory follows occupancy, not the full cube.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "Trilinear",
    "build_index",
    "cell_occupancy",
    "corners",
    "dense_values",
    "occupied_coords",
    "trilinear",
    "voxel_size",
    "world_to_grid",
]

def build_index(occ: Tensor) -> Tensor:
    """Index volume ``[X, Y, Z]`` int32 from an occupancy mask ``occ [X, Y, Z]`` bool.

    Rows are assigned in C order of the occupied points; empty points get -1.
    """
    flat = occ.reshape(-1)
    idx = torch.full(flat.shape, -1, dtype=torch.int32, device=occ.device)
    n = int(flat.sum())
    idx[flat] = torch.arange(n, dtype=torch.int32, device=occ.device)
    return idx.reshape(occ.shape)


def occupied_coords(index: Tensor) -> Tensor:
    """``[M, 3]`` long grid coordinates of the rows of ``index [X, Y, Z]`` (row order)."""
    flat = index.reshape(-1)
    pos = torch.nonzero(flat >= 0).squeeze(1)
    order = torch.argsort(flat[pos].long())
    pos = pos[order]
    _, Y, Z = index.shape
    return torch.stack([pos // (Y * Z), (pos // Z) % Y, pos % Z], -1)


def voxel_size(bounds: Tensor, reso: list[int] | tuple[int, ...]) -> Tensor:
    """``[3]`` spacing of grid points: ``(hi - lo) / (reso - 1)``."""
    r = torch.as_tensor(reso, dtype=bounds.dtype, device=bounds.device)
    return (bounds[1] - bounds[0]) / (r - 1).clamp_min(1)


def world_to_grid(x: Tensor, bounds: Tensor, reso) -> Tensor:
    """World points ``[..., 3]`` -> continuous grid coordinates ``[..., 3]``, clamped to ``[0, reso-1]``."""
    g = (x - bounds[0]) / voxel_size(bounds, reso)
    hi = torch.as_tensor(reso, dtype=x.dtype, device=x.device) - 1
    return torch.minimum(g.clamp_min(0), hi)


def cell_occupancy(index: Tensor) -> Tensor:
    """``[X, Y, Z]`` bool: cell with lower corner ``(i, j, k)`` has at least one occupied corner.

    (The last plane along each axis is a degenerate cell; it is true where the point itself is occupied.)
    """
    occ = (index >= 0).float()[None, None]
    pooled = F.max_pool3d(F.pad(occ, (0, 1, 0, 1, 0, 1)), kernel_size=2, stride=1)
    return pooled[0, 0] > 0


def corners(index: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """Rows and trilinear weights of the 8 corners around grid points ``g [S, 3]`` (in ``[0, reso-1]``).

    Returns:
        rows ``[S, 8]`` long (0 where the corner is empty) and weights ``[S, 8]`` (0 where empty),
        so ``sum_c w[:, c] * table[rows[:, c]]`` is the interpolation with empty corners = 0.
    """
    X, Y, Z = index.shape
    hi = torch.tensor([X - 2, Y - 2, Z - 2], device=g.device)
    base = torch.minimum(g.floor().long().clamp_min(0), hi)  # lower corner; reso >= 2 per axis
    f = g - base.to(g.dtype)  # [S, 3] in [0, 1]
    lin = (base[:, 0] * Y + base[:, 1]) * Z + base[:, 2]
    offs = torch.tensor([(i * Y + j) * Z + k for i in (0, 1) for j in (0, 1) for k in (0, 1)], device=g.device)
    rows = index.reshape(-1)[lin[:, None] + offs[None]].long()  # [S, 8]
    wx, wy, wz = (torch.stack([1 - f[:, a], f[:, a]], -1) for a in range(3))  # [S, 2] each
    w = (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 8)
    empty = rows < 0
    return rows.clamp_min(0), w.masked_fill(empty, 0.0)


class Trilinear(torch.autograd.Function):
    """``out [S, C] = sum_c w[:, c] * table[rows[:, c]]`` with a scatter backward (no ``[S, 8, C]`` buffer)."""

    @staticmethod
    def forward(ctx, table: Tensor, rows: Tensor, w: Tensor) -> Tensor:
        out = torch.zeros(rows.shape[0], table.shape[1], dtype=table.dtype, device=table.device)
        for c in range(rows.shape[1]):
            out.addcmul_(table.index_select(0, rows[:, c]), w[:, c : c + 1])
        ctx.save_for_backward(rows, w)
        ctx.m = table.shape[0]
        return out

    @staticmethod
    def backward(ctx, grad: Tensor):
        rows, w = ctx.saved_tensors
        gt = torch.zeros(ctx.m, grad.shape[1], dtype=grad.dtype, device=grad.device)
        for c in range(rows.shape[1]):
            gt.index_add_(0, rows[:, c], grad * w[:, c : c + 1])
        return gt, None, None


def trilinear(table: Tensor, rows: Tensor, w: Tensor) -> Tensor:
    """Interpolate ``table [M, C]`` at samples given by :func:`corners` -> ``[S, C]`` (differentiable in table)."""
    return Trilinear.apply(table, rows, w)


def dense_values(index: Tensor, table: Tensor) -> Tensor:
    """Dense ``[X, Y, Z, C]`` volume of ``table [M, C]`` (empty points 0); for tests and export."""
    out = torch.zeros(*index.shape, table.shape[1], dtype=table.dtype, device=table.device)
    m = index >= 0
    out[m] = table[index[m].long()]
    return out
