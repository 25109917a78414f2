"""The stage-2 batch hook: each batch's colour targets (:class:`~arcsem.plugins.ColorTargets`) from the
pseudo-colours and the TCM/CCM guidance."""
from __future__ import annotations

import dataclasses

import torch

from ..plugins import Batch, ColorTargets
from .guidance import Guidance
from .references import References

__all__ = ["ColorTargetHook"]


class ColorTargetHook:
    """The stage-2 ``batch_hook``: gives each batch its :class:`~arcsem.plugins.ColorTargets` from the pseudo-colours
    and the guidance. :meth:`to` puts everything it holds (the loss space's extractor too) on the run's device, so
    a step gathers its targets there, without host transfers.

    Args: refs (``R`` references); pseudo ``[N, H, W, 3]`` and valid ``[N, H, W]`` of every training view; guidance
    (None without TCM/CCM); space: the TCM loss space (the extractor, or a colour space); uncovered_only: TCM/CCM
    targets only on the cells where under half the pixels are ``covered [N, H, W]`` (default ``valid``: have a
    pseudo-colour; the run passes the pixels before the grey prior, :mod:`arcsem.colorize.prior`)
    (``colorize.guard.uncovered_only``).
    """

    def __init__(self, refs: References, pseudo: torch.Tensor, valid: torch.Tensor, guidance: Guidance | None,
                 space=None, tcm_downscale: int = 4, ccm_downscale: int = 16, uncovered_only: bool = False,
                 covered: torch.Tensor | None = None):
        n = pseudo.shape[0]
        slot = torch.full((n,), len(refs), dtype=torch.long)  # reference position of each view; R: none
        slot[refs.indices] = torch.arange(len(refs))
        self.slot, self.is_ref = slot, slot < len(refs)
        self.ref_views = set(refs.indices.tolist())  # host-side: which views a batch holds is known there
        self.references = torch.cat([refs.images.float(), torch.zeros_like(refs.images[:1]).float()])  # [R + 1, ...]
        self.pseudo, self.valid, self.guidance, self.space = pseudo, valid, guidance, space
        self.covered = valid if covered is None else covered
        self.tcm_downscale, self.ccm_downscale = tcm_downscale, ccm_downscale
        self.uncovered_only, self._uncovered = uncovered_only, {}
        self.active = self._active_views() if guidance is not None else {}

    def _active_views(self) -> dict[int, tuple[bool, bool]]:
        """``{view: (tcm, ccm)}`` for every non-reference view: whether any TCM location (CCM cell) of it keeps a
        target (:meth:`_guided`). Decided once, on the host, from the fixed guidance: a batch whose views have none
        skips that loss's pass (with five references the demo's uncovered cells are none, and TCM ran VGG every step
        to add 0)."""
        out = {}
        for v in range(self.pseudo.shape[0]):
            if v not in self.ref_views:
                g = self._guided([v], torch.tensor([v], device=self.pseudo.device))
                tcm = g["tcm_valid"] is None or any(bool(ok.any()) for ok in g["tcm_valid"])
                out[v] = (tcm, bool(g["ccm_valid"].any()))
        return out

    def _guided(self, views: list[int], idx: torch.Tensor) -> dict:
        """The guidance's targets of ``views`` stacked (``idx``: the same views, a tensor on the targets' device):
        ``tcm_guidance`` and ``tcm_valid`` (None: all) per block, ``ccm_target``, ``ccm_valid``; with
        ``uncovered_only`` the valid locations are only those ``covered`` leaves."""
        t = [self.guidance.targets(v) for v in views]
        stack = (lambda xs: xs[0][None]) if len(views) == 1 else torch.stack  # one view: a view, no copy
        out = {"tcm_guidance": [stack([x["tcm_guidance"][b] for x in t]) for b in range(len(t[0]["tcm_guidance"]))],
               "tcm_valid": ([stack([x["tcm_valid"][b] for x in t]) for b in range(len(t[0]["tcm_valid"]))]
                             if "tcm_valid" in t[0] else None),
               "ccm_target": stack([x["ccm_target"] for x in t]), "ccm_valid": stack([x["ccm_valid"] for x in t])}
        if self.uncovered_only:
            blocks = out["tcm_valid"] or [torch.ones(g.shape[:1] + g.shape[2:], dtype=torch.bool, device=g.device)
                                          for g in out["tcm_guidance"]]
            out["tcm_valid"] = [ok & self.uncovered(idx, tuple(ok.shape[-2:])) for ok in blocks]
            out["ccm_valid"] = out["ccm_valid"] & self.uncovered(idx, tuple(out["ccm_valid"].shape[-2:]))
        return out

    def uncovered(self, idx: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
        """``[B, h, w]`` bool: the cells of a ``shape`` grid over views ``idx`` where under half the pixels are
        covered (computed once per grid for all views, on the targets' device)."""
        if shape not in self._uncovered:
            from .guard import uncovered_cells

            self._uncovered[shape] = uncovered_cells(self.covered, shape)
        return self._uncovered[shape][idx]

    def to(self, device) -> ColorTargetHook:
        """Move every tensor, the guidance and the loss space (a module: the VGG) to ``device``; returns self."""
        for name in ("slot", "is_ref", "references", "pseudo", "valid", "covered"):
            setattr(self, name, getattr(self, name).to(device))
        self._uncovered = {k: v.to(device) for k, v in self._uncovered.items()}
        if self.guidance is not None:
            self.guidance.to(device)
        if isinstance(self.space, torch.nn.Module):
            self.space.to(device)
        return self

    def __call__(self, batch: Batch) -> Batch:
        views = list(batch.views) if batch.views else batch.indices.tolist()
        idx = batch.indices.to(self.pseudo.device)
        targets = ColorTargets(is_reference=self.is_ref[idx], reference=self.references[self.slot[idx]],
                               pseudo=self.pseudo[idx], pseudo_valid=self.valid[idx], tcm_space=self.space,
                               tcm_downscale=self.tcm_downscale, ccm_downscale=self.ccm_downscale,
                               references_only=all(v in self.ref_views for v in views))
        others = [v for v in views if v not in self.ref_views]
        targets.tcm_idle = not any(self.active.get(v, (True, True))[0] for v in others)
        targets.ccm_idle = not any(self.active.get(v, (True, True))[1] for v in others)
        if self.guidance is not None:
            g = self._guided(views, idx)
            targets.tcm_guidance, targets.tcm_valid = g["tcm_guidance"], g["tcm_valid"]
            targets.ccm_target, targets.ccm_valid = g["ccm_target"], g["ccm_valid"]
        return dataclasses.replace(batch, color=targets)
