"""Total variation of a sparse grid on a random subset of voxels (Plenoxels' regulariser).

``TV = sum_{v in subset} sum_channels sqrt(eps + dx^2 + dy^2 + dz^2)`` with forward differences
``dx = V[x+1, y, z] - V[x, y, z]``; an empty neighbour reads 0 (as in rendering), a neighbour
outside the grid gives a zero difference. svox2 evaluates it on a random 1% of voxels each step.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["tv_sparse", "random_rows"]


def random_rows(num_rows: int, frac: float, generator: torch.Generator | None = None, device=None) -> Tensor:
    """``[max(1, frac*M)]`` random rows out of ``M`` (drawn with replacement: no O(M) permutation per step)."""
    k = min(num_rows, max(1, int(round(frac * num_rows))))
    return torch.randint(num_rows, (k,), generator=generator, device=device)


def tv_sparse(index: Tensor, coords: Tensor, table: Tensor, rows: Tensor, eps: float = 1e-5) -> Tensor:
    """TV of ``table [M, C]`` at the stored points ``rows [K]``.

    Args:
        index: ``[X, Y, Z]`` int32 row per grid point (-1 empty).
        coords: ``[M, 3]`` long grid coordinates of each row.
        table: ``[M, C]`` values (raw density or flattened SH).
        rows: ``[K]`` long, the points to evaluate.
    Returns:
        scalar: sum over the ``K`` points and ``C`` channels of ``sqrt(eps + |grad|^2)``.
    """
    c = coords[rows]  # [K, 3]
    v = table[rows]  # [K, C]
    reso = torch.tensor(index.shape, device=c.device)
    sq = torch.zeros_like(v)
    for a in range(3):
        n = c.clone()
        n[:, a] += 1
        inside = n[:, a] < reso[a]
        nrow = torch.full_like(rows, -1)
        nrow[inside] = index[n[inside, 0], n[inside, 1], n[inside, 2]].long()
        nv = torch.where((nrow >= 0)[:, None], table[nrow.clamp_min(0)], torch.zeros_like(v))
        d = torch.where(inside[:, None], nv - v, torch.zeros_like(v))
        sq = sq + d * d
    return torch.sqrt(eps + sq).sum()
