"""RMSProp over the rows a step touched (svox2's ``rmsprop_step`` with its sparse gradient indexer).

The fused marcher and the sparse TV return sparse COO gradients (:mod:`.fused`, :mod:`.tv`): only the
voxels that the step's rays or TV samples reached. svox2 updates just those rows, squared average and
value; the others keep both (a "lazy" RMSProp), which makes a step cost what it touches rather than
the size of the grid. A dense gradient (the PyTorch path) updates every element, as ``torch.optim.RMSprop``.
"""
from __future__ import annotations

import torch

__all__ = ["SparseRMSprop"]


class SparseRMSprop(torch.optim.Optimizer):
    """``v = alpha v + (1 - alpha) g^2``, ``p -= lr g / (sqrt(v) + eps)`` on the rows of a sparse ``g``.

    Args:
        params: parameters or param groups (as any optimiser).
        lr: rate (the trainer sets it every step from the backbone's schedule).
        alpha: decay of the squared average (svox2: 0.95).
        eps: added to the root mean square.
    """

    def __init__(self, params, lr: float = 1e-2, alpha: float = 0.95, eps: float = 1e-8):
        if not 0.0 <= alpha < 1.0:
            raise ValueError(f"alpha must be in [0, 1), got {alpha}")
        super().__init__(params, {"lr": lr, "alpha": alpha, "eps": eps})

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            lr, alpha, eps = group["lr"], group["alpha"], group["eps"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if "square_avg" not in state:
                    state["step"] = torch.tensor(0.0)
                    state["square_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] += 1
                _update(p, p.grad, state["square_avg"], lr, alpha, eps)
        return loss


def _update(p: torch.Tensor, g: torch.Tensor, sq: torch.Tensor, lr: float, alpha: float, eps: float) -> None:
    if not g.is_sparse:
        sq.mul_(alpha).addcmul_(g, g, value=1 - alpha)
        p.addcdiv_(g, sq.sqrt().add_(eps), value=-lr)
        return
    rows, v = _rows_and_sums(g)
    s = sq.index_select(0, rows).mul_(alpha).addcmul_(v, v, value=1 - alpha)
    sq.index_copy_(0, rows, s)
    p.index_add_(0, rows, v / s.sqrt().add_(eps), alpha=-lr)


def _rows_and_sums(g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sorted unique rows ``[n]`` of a sparse COO ``g`` and the sum of its values per row ``[n, ...]``.

    A sum of sparse gradients (marcher + TV) is not coalesced; rather than sort its entries, mark the rows
    in a byte mask (one pass over ``M`` bytes) and add the values into a dense table at those rows only."""
    if g.is_coalesced():
        return g.indices()[0], g.values()
    idx, vals = g._indices()[0], g._values()
    mark = torch.zeros(g.shape[0], dtype=torch.bool, device=idx.device)
    mark[idx] = True
    rows = mark.nonzero().squeeze(1)
    where = torch.full((g.shape[0],), -1, dtype=torch.long, device=idx.device)
    where[rows] = torch.arange(rows.numel(), device=idx.device)
    out = torch.zeros(rows.numel(), *vals.shape[1:], dtype=vals.dtype, device=vals.device)
    return rows, out.index_add_(0, where[idx], vals)
