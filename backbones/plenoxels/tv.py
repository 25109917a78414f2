"""Total variation of a sparse grid on a random subset of voxels (Plenoxels' regulariser).

``TV = sum_{v in subset} sum_channels sqrt(eps + dx^2 + dy^2 + dz^2)`` with forward differences
``dx = V[x+1, y, z] - V[x, y, z]``; an empty neighbour reads 0 (as in rendering), a neighbour
outside the grid gives a zero difference. svox2 evaluates it on a random 1% of voxels each step.
The gradient is a sparse COO tensor over the voxels and neighbours it reached (dense on request).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["random_rows", "tv_sparse"]


def random_rows(num_rows: int, frac: float, generator: torch.Generator | None = None, device=None) -> Tensor:
    """``[max(1, frac*M)]`` random rows out of ``M`` (drawn with replacement: no O(M) permutation per step)."""
    k = min(num_rows, max(1, round(frac * num_rows)))
    return torch.randint(num_rows, (k,), generator=generator, device=device)


def _neighbours(index: Tensor, coords: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
    """Rows of the +x, +y, +z neighbours ``[3, K]`` (-1: empty or outside) and whether inside ``[3, K]``."""
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
    return torch.stack(nbr), torch.stack(inside)


class _TV(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, index, coords, rows, eps, sparse):
        flat = table.detach().reshape(table.shape[0], -1)
        nrow, inside = _neighbours(index, coords, rows)
        v = flat[rows]  # [K, C]
        nv = torch.where((nrow >= 0)[..., None], flat[nrow.clamp_min(0)], torch.zeros((), dtype=flat.dtype))
        d = torch.where(inside[..., None], nv - v[None], torch.zeros((), dtype=flat.dtype))  # [3, K, C]
        s = torch.sqrt(eps + (d * d).sum(0))  # [K, C]
        ctx.save_for_backward(rows, nrow, d, s)
        ctx.shape, ctx.sparse = table.shape, sparse
        return s.sum()

    @staticmethod
    def backward(ctx, g):
        rows, nrow, d, s = ctx.saved_tensors
        q = g * d / s[None]  # [3, K, C]: d TV / d neighbour (0 outside the grid)
        stored = nrow >= 0
        idx = torch.cat([rows, nrow[stored]])
        vals = torch.cat([-q.sum(0), q[stored]]).reshape(-1, *ctx.shape[1:])
        grad = torch.sparse_coo_tensor(idx[None], vals, ctx.shape, check_invariants=False).coalesce()
        return (grad if ctx.sparse else grad.to_dense()), None, None, None, None, None


def tv_sparse(index: Tensor, coords: Tensor, table: Tensor, rows: Tensor, eps: float = 1e-5,
              sparse_grad: bool = True) -> Tensor:
    """TV of ``table [M, ...]`` (channels: the trailing dimensions) at the stored points ``rows [K]``.

    Args:
        index: ``[X, Y, Z]`` int32 row per grid point (-1 empty).
        coords: ``[M, 3]`` long grid coordinates of each row.
        table: ``[M]`` or ``[M, ...]`` values (raw density ``[M]``, SH ``[M, K, 3]``).
        rows: ``[K]`` long, the points to evaluate (repeats allowed).
        sparse_grad: the gradient of ``table`` as a sparse COO tensor (else dense).
    Returns:
        scalar: sum over the ``K`` points and the channels of ``sqrt(eps + |grad|^2)``.
    """
    return _TV.apply(table, index, coords, rows, eps, sparse_grad)
