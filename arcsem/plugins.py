"""The plugin contracts: :class:`Backbone`, :class:`Loss`, the two registries, and the batch type.

A backbone renders cameras to a :data:`RenderOutput` dict; a loss turns a render and a batch into an
unweighted scalar. Names, provided outputs and required outputs are class attributes so that
``arcsem-plugins`` and the trainer can check compatibility before any work is done.

RenderOutput keys (``C`` cameras of ``H x W``; ray backbones use ``[R, ...]`` for ray batches):
    ``rgb`` ``[C,H,W,3]``, ``alpha`` ``[C,H,W,1]``, ``depth`` ``[C,H,W,1]`` (expected z-depth),
    ``median_depth`` ``[C,H,W,1]``, ``normal`` ``[C,H,W,3]`` (world, camera-facing),
    ``distortion`` ``[C,H,W,1]``, plus backbone-specific auxiliaries (e.g. ``means2d`` for
    densification statistics).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import torch
from torch import Tensor, nn

from .cameras import Cameras
from .registry import Registry

__all__ = ["BACKBONES", "LOSSES", "Backbone", "Batch", "Loss", "RenderOutput"]

BACKBONES = Registry("backbone", "arcsem.backbones")
LOSSES = Registry("loss", "arcsem.losses")

RenderOutput = dict[str, Tensor]


@dataclass
class Batch:
    """What a loss sees besides the render.

    Image batches: ``images [C,H,W,3]``, ``masks [C,H,W,1]`` or None, ``indices [C]`` view indices in
    the split. Ray batches (``rays_o``/``rays_d`` set): ``images [R,3]`` target colours per ray.
    ``extras`` carries stage-specific targets (pseudo-colours, guidance features, ...).
    """

    cameras: Cameras
    images: Tensor
    indices: Tensor
    masks: Tensor | None = None
    rays_o: Tensor | None = None
    rays_d: Tensor | None = None
    ray_image_ids: Tensor | None = None
    extras: dict[str, Any] | None = None


class Backbone(nn.Module):
    """Base class of scene representations.

    Subclasses define ``Config`` (a dataclass whose defaults are the paper's), ``provides`` and
    ``render``. ``batch_mode`` tells the trainer whether to feed whole images or random ray batches.
    """

    name: ClassVar[str]
    provides: ClassVar[frozenset[str]] = frozenset({"rgb", "alpha", "depth"})
    batch_mode: ClassVar[Literal["image", "rays"]] = "image"

    @dataclass
    class Config:
        pass

    def __init__(self, cfg: Any, scene: Any = None, **runtime: Any):
        super().__init__()
        self.cfg = cfg

    def render(self, cams: Cameras, **kw: Any) -> RenderOutput:
        """Render ``C`` cameras; returns at least the keys in ``provides``."""
        raise NotImplementedError

    def render_rays(self, rays_o: Tensor, rays_d: Tensor, image_ids: Tensor, **kw: Any) -> RenderOutput:
        """Ray backbones: render ``[R,3]`` rays (directions with unit camera z)."""
        raise NotImplementedError(f"{self.name} renders whole images only")

    def param_groups(self, stage: str) -> dict[str, list[nn.Parameter]]:
        """Parameters by optimiser group; ``stage`` is ``"geometry"`` (stage 1) or ``"color"`` (stage 2)."""
        raise NotImplementedError

    def pre_backward(self, step: int, out: RenderOutput) -> None:
        """Hook before ``loss.backward()`` (e.g. retain gradients of screen-space means)."""

    def post_backward(self, step: int, out: RenderOutput, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        """Hook after backward, before the optimiser step (densify, prune, upsample)."""

    def num_primitives(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def export(self, path: str) -> None:
        """Write the model in a format other tools read (PLY for Gaussians)."""
        raise NotImplementedError

    def export_viewer(self, folder: str, cams: Cameras, names: list[str], centre: Tensor,
                      iteration: int) -> dict[str, str]:
        """Write the folder layout that common 3DGS viewers load (``point_cloud/iteration_N/point_cloud.ply``
        and ``cameras.json`` of ``cams`` named ``names``); returns the paths. Gaussians only."""
        raise NotImplementedError(f"{self.name}: no viewer export")


class Loss(nn.Module):
    """Base class of loss terms: ``forward`` returns an unweighted scalar; the trainer weights it."""

    name: ClassVar[str]
    requires: ClassVar[frozenset[str]] = frozenset({"rgb"})

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0

    def __init__(self, cfg: Any, **runtime: Any):
        super().__init__()
        self.cfg = cfg

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        raise NotImplementedError
