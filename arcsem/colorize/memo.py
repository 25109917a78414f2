"""Each view rendered once after stage 2's training: the colour metrics, the coverage metrics and the PNGs all
render the same training and held-out views of the frozen, trained model (on a NeRF-synthetic chair, 200 held-out
views at 288 px, each was rendered four times: 600 of evaluation's renders and 200 of the PNGs' were repeats).

:class:`RenderMemo` stands in for the backbone where those consumers call ``render(cams)``: one camera's image
outputs (``[1, H, W, k]`` tensors: ``rgb``, ``depth``, ``alpha`` ...) are kept, up to a memory budget, and handed out
again for the same camera. Only for a model that no longer changes; the outputs are shared, never to be written in
place (every consumer reads them).
"""
from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

__all__ = ["RenderMemo"]


def _key(cams) -> tuple:
    """What decides a render of one camera: its pose, intrinsics, size, model and image id (the ACT it selects)."""
    return (cams.model, cams.width, cams.height, cams.world_to_cam.cpu().numpy().tobytes(),
            cams.K.cpu().numpy().tobytes(), cams.image_ids.cpu().numpy().tobytes())


class RenderMemo:
    """``backbone.render`` for single cameras, each rendered once while ``budget_mb`` lasts (then as before).

    Attributes:
        backbone: the trained model (anything else is read from it).
        hits, renders: renders handed out again / made (``metrics.json``: ``stage2.post_renders``).
    """

    def __init__(self, backbone: Any, budget_mb: float = 1024.0):
        self.backbone, self.budget = backbone, int(budget_mb * 2**20)
        self.used, self.hits, self.renders = 0, 0, 0
        self._kept: dict[tuple, dict[str, Tensor]] = {}

    def render(self, cams, **kw: Any) -> dict[str, Tensor]:
        """The image outputs (4-D tensors) of ``backbone.render(cams)``; kept for one camera without options."""
        if kw or len(cams) != 1:
            self.renders += 1
            return self.backbone.render(cams, **kw)
        key = _key(cams)
        if key in self._kept:
            self.hits += 1
            return self._kept[key]
        with torch.no_grad():
            out = {k: v.detach() for k, v in self.backbone.render(cams).items() if torch.is_tensor(v) and v.ndim == 4}
        self.renders += 1
        size = sum(v.numel() * v.element_size() for v in out.values())
        if self.used + size <= self.budget:
            self._kept[key], self.used = out, self.used + size
        return out

    def __getattr__(self, name: str) -> Any:  # (only for names not set in __init__)
        return getattr(self.backbone, name)
