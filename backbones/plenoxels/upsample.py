"""Coarse-to-fine: trilinear resampling of a sparse grid and pruning of unused voxels (pure functions).

svox2 upsamples on a schedule, then keeps only voxels whose largest rendering weight over the
training rays reaches ``weight_thresh / z_reso`` (or, alternatively, whose density reaches a
threshold), dilated by 2 voxels so that surfaces can still move.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from .grid import build_index, cell_occupancy, corners, trilinear

__all__ = ["dilate", "max_weights", "prune", "resample"]


def resample(index: Tensor, tables: list[Tensor], new_reso: list[int], chunk: int = 1 << 20) -> tuple[Tensor, list[Tensor]]:
    """Trilinearly resample a sparse grid to ``new_reso``.

    Grid points span the same box at both resolutions (vertex grid), so new point ``j`` sits at old
    grid coordinate ``j * (N - 1) / (N' - 1)`` and a linear field is reproduced exactly. A new point
    is stored when its old cell has at least one occupied corner.

    Args:
        index: ``[X, Y, Z]`` int32 old index volume.
        tables: value tables ``[M, ...]`` (e.g. density ``[M]``, SH ``[M, K, 3]``).
        new_reso: ``[X', Y', Z']``.
    Returns:
        new index ``[X', Y', Z']`` and the new tables ``[M', ...]``.
    """
    old = torch.tensor(index.shape, dtype=torch.float64)
    new = torch.tensor(new_reso, dtype=torch.float64)
    ratio = (old - 1) / (new - 1)
    X2, Y2, Z2 = new_reso
    cocc = cell_occupancy(index).reshape(-1)
    flat_tabs = [t.detach().reshape(t.shape[0], -1) for t in tables]
    occ_parts, val_parts = [], [[] for _ in tables]
    slab = max(1, chunk // (Y2 * Z2))
    yz = torch.stack(torch.meshgrid(torch.arange(Y2), torch.arange(Z2), indexing="ij"), -1).reshape(-1, 2)
    for x0 in range(0, X2, slab):
        xs = torch.arange(x0, min(X2, x0 + slab))
        pts = torch.cat([xs.repeat_interleave(yz.shape[0])[:, None], yz.repeat(len(xs), 1)], 1)
        g = (pts.double() * ratio).clamp(min=torch.zeros(3, dtype=torch.float64), max=old - 1)
        b = torch.minimum(g.floor().long(), (old - 1).long())
        keep = cocc[(b[:, 0] * index.shape[1] + b[:, 1]) * index.shape[2] + b[:, 2]]
        occ_parts.append(keep)
        rows, w = corners(index, g[keep])
        for i, t in enumerate(flat_tabs):
            val_parts[i].append(trilinear(t.double(), rows, w).to(t.dtype))
    occ = torch.cat(occ_parts).reshape(X2, Y2, Z2)
    out = [torch.cat(v).reshape(-1, *t.shape[1:]) for v, t in zip(val_parts, tables)]
    return build_index(occ), out


def dilate(mask: Tensor, radius: int) -> Tensor:
    """Grow a ``[X, Y, Z]`` bool mask by ``radius`` voxels (a cube of side ``2 radius + 1``)."""
    if radius <= 0:
        return mask
    k = 2 * radius + 1
    return F.max_pool3d(mask.float()[None, None], kernel_size=k, stride=1, padding=radius)[0, 0] > 0


def prune(index: Tensor, keep: Tensor, radius: int = 2) -> tuple[Tensor, Tensor]:
    """Drop stored points not in ``keep [M]`` (after dilating the kept set by ``radius`` voxels).

    Returns:
        new index ``[X, Y, Z]`` and ``rows [M']`` long: old row of each new row (gather the tables with it).
    """
    occ = index >= 0
    kept = torch.zeros_like(occ)
    kept[occ] = keep[index[occ].long()]
    new_occ = dilate(kept, radius) & occ
    new_index = build_index(new_occ)
    rows = torch.empty(int(new_occ.sum()), dtype=torch.long, device=index.device)
    rows[new_index[new_occ].long()] = index[new_occ].long()
    return new_index, rows


def max_weights(num_rows: int, samples: list[tuple[Tensor, Tensor, Tensor]]) -> Tensor:
    """Largest rendering weight ``[M]`` that reached each stored point.

    ``samples``: ``(rows [A, 8], trilinear weights [A, 8], rendering weights [A])`` from
    ``render_grid(..., return_samples=True)``; a sample counts for each corner it interpolates from.
    """
    out = torch.zeros(num_rows)
    for rows, wtri, w in samples:
        hit = wtri > 0
        src = w[:, None].expand_as(rows)[hit].to(out.dtype)
        out.scatter_reduce_(0, rows[hit].cpu(), src.cpu(), reduce="amax")
    return out
