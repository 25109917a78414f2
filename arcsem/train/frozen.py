"""Stage 2's renders of the frozen geometry: each training view's :meth:`~arcsem.plugins.Backbone.colour_operator`,
made the first time the view is drawn and used for every later step that draws it, within a memory budget.

A backbone without one (the default) renders as usual, and so do the views past the budget. The geometry does not
change in stage 2 (only the colour parameter groups are optimised), which is what keeps a recorded render valid.
"""
from __future__ import annotations

import logging

import torch
from torch import nn

from ..plugins import Batch, RenderOutput

__all__ = ["FrozenViews"]

log = logging.getLogger(__name__)


class FrozenViews:
    """The recorded renders of the views of a split (by index), within ``budget_mb`` MiB."""

    def __init__(self, budget_mb: int):
        self.budget, self.used = int(budget_mb) * 2**20, 0
        self.ops: dict[int, object] = {}
        self.refused: set[int] = set()  # views that render as usual (over the budget)
        self.supported = True  # False once the backbone has no colour operator

    def render(self, backbone: nn.Module, batch: Batch) -> RenderOutput | None:
        """``batch`` rendered from the recorded views where every view of it has one (recording those not yet
        recorded), else None (the caller renders as usual)."""
        views = batch.views
        if not self.supported or not views or len(views) != len(batch.cameras):
            return None
        ops = [self._op(backbone, v, batch.cameras[k:k + 1]) for k, v in enumerate(views)]
        if any(op is None for op in ops):
            return None
        outs = [op() for op in ops]
        if len(outs) == 1:
            return outs[0]
        return {k: torch.cat([o[k] for o in outs]) if torch.is_tensor(outs[0][k]) else outs[0][k] for k in outs[0]}

    def summary(self) -> dict:
        """What ``metrics.json`` records: views recorded, views over the budget, MiB held, whether the backbone has
        a colour operator at all."""
        return {"supported": self.supported, "views": len(self.ops), "over_budget": len(self.refused),
                "mib": round(self.used / 2**20, 1), "budget_mib": self.budget // 2**20}

    def _op(self, backbone: nn.Module, view: int, cams):
        op = self.ops.get(view)
        if op is not None or view in self.refused or not self.supported:
            return op
        op = backbone.colour_operator(cams)
        if op is None:
            self.supported = False
            return None
        if self.used + op.nbytes > self.budget:
            self.refused.add(view)
            if len(self.refused) == 1:
                log.info("stage 2: frozen-geometry renders use %.0f MiB for %d views; the others render as usual "
                         "(colorize.frozen_mb)", self.used / 2**20, len(self.ops))
            return None
        self.used += op.nbytes
        self.ops[view] = op
        return op
