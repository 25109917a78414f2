"""Total variation of a sparse grid on a random subset of voxels (Plenoxels' regulariser).

``TV = sum_{v in subset} sum_channels sqrt(eps + dx^2 + dy^2 + dz^2)`` with forward differences
``dx = V[x+1, y, z] - V[x, y, z]``; an empty neighbour reads 0 (as in rendering), a neighbour
outside the grid gives a zero difference. svox2 evaluates it on a random 1% of voxels each step.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["random_rows", "tv_sparse"]


def random_rows(num_rows: int, frac: float, generator: torch.Generator | None = None, device=None) -> Tensor:
    """``[max(1, frac*M)]`` random rows out of ``M`` (drawn with replacement: no O(M) permutation per step)."""
    k = min(num_rows, max(1, round(frac * num_rows)))
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
    reso = torch.tensor(index.shape, device=c.device)
    nbr, inside = [], []
    for a in range(3):
        n = c.clone()
        n[:, a] += 1
        ok = n[:, a] < reso[a]
        n[:, a] = torch.minimum(n[:, a], reso[a] - 1)
        nbr.append(index[n[:, 0], n[:, 1], n[:, 2]].long().masked_fill(~ok, -1))
        inside.append(ok)
    nrow = torch.stack(nbr)  # [3, K]: neighbour rows, -1 empty or outside
    vals = table[torch.cat([rows, nrow.clamp_min(0).reshape(-1)])]  # one gather: one dense backward
    v, nv = vals[: rows.shape[0]], vals[rows.shape[0] :].reshape(3, rows.shape[0], -1)
    nv = torch.where((nrow >= 0)[..., None], nv, torch.zeros_like(nv))  # empty neighbour reads 0
    d = torch.where(torch.stack(inside)[..., None], nv - v[None], torch.zeros_like(nv))  # outside: no difference
    return torch.sqrt(eps + (d * d).sum(0)).sum()
