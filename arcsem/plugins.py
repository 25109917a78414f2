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

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import torch
from torch import Tensor, nn

from .cameras import Cameras
from .configs import GroupSchedule
from .registry import BACKBONES, LOSSES  # made without torch: arcsem.schemas reads Configs at start-up

__all__ = ["BACKBONES", "LOSSES", "Backbone", "Batch", "ColorTargets", "Loss", "RenderOutput"]

RenderOutput = dict[str, Tensor]


@dataclass
class ColorTargets:
    """The colourisation stage's targets for a batch of ``C`` whole views (filled by stage 2's batch hook).

    Attributes:
        is_reference: ``[C]`` bool, the artist-coloured views (``reference_l1`` only acts on them; the others skip them).
        reference: ``[C, H, W, 3]`` the artist colours (zeros for other views).
        pseudo: ``[C, H, W, 3]`` pseudo-colours; ``pseudo_valid``: ``[C, H, W]`` bool, the pixels that have one.
        tcm_guidance: per feature block ``[C, D_b, h_b, w_b]`` (None without TCM/CCM guidance); ``tcm_valid``: per
            block ``[C, h_b, w_b]`` bool, the locations whose match passed the guard (None: all).
        tcm_space: the TCM loss space, images ``[C, h, w, 3]`` -> per block ``[C, D_b, h_b, w_b]``.
        tcm_downscale: renders are scaled down by this before ``tcm_space``.
        ccm_target: ``[C, hc, wc, 3]`` matched reference cell colours; ``ccm_valid``: ``[C, hc, wc]`` bool.
        ccm_downscale: the CCM cell size in pixels.
        references_only: every view of the batch is a reference (known on the host, where the views were drawn):
            TCM and CCM, which act on the other views only, skip their feature pass (a VGG forward and backward).
        tcm_idle, ccm_idle: no non-reference view of the batch has a TCM location (CCM cell) whose match passed the
            guard (``tcm_valid``/``ccm_valid`` all false: the loss is 0), known on the host: the loss skips its pass.
    """

    is_reference: Tensor
    reference: Tensor
    pseudo: Tensor
    pseudo_valid: Tensor
    tcm_guidance: list[Tensor] | None = None
    tcm_valid: list[Tensor] | None = None
    tcm_space: Callable[[Tensor], list[Tensor]] | None = None
    tcm_downscale: int = 4
    ccm_target: Tensor | None = None
    ccm_valid: Tensor | None = None
    ccm_downscale: int = 16
    references_only: bool = False
    tcm_idle: bool = False
    ccm_idle: bool = False


@dataclass
class Batch:
    """What a loss sees besides the render.

    Image batches: ``images [C,H,W,3]``, ``masks [C,H,W,1]`` or None, ``indices [C]`` view indices in
    the split (on the model's device) and ``views`` the same as Python ints (read without a device transfer; empty
    where a batch was made without them). Ray batches (``rays_o``/``rays_d`` set): ``images [R,3]`` target colours
    per ray.
    ``color``: the colourisation targets (stage 2 only; a loss that reads them declares ``needs = {"color"}``).
    """

    cameras: Cameras
    images: Tensor
    indices: Tensor
    masks: Tensor | None = None
    rays_o: Tensor | None = None
    rays_d: Tensor | None = None
    ray_image_ids: Tensor | None = None
    color: ColorTargets | None = None
    views: tuple[int, ...] = ()


class Backbone(nn.Module):
    """Base class of scene representations: every hook the trainer (stage 1), stage 2 and the exports call.

    A plugin defines ``Config`` (a dataclass whose defaults are the paper's), ``provides`` and :meth:`render`
    (plus :meth:`render_rays` for ``batch_mode = "rays"``), and :meth:`param_groups`. Every other hook has a
    default here; nothing outside this list is called on a backbone (tests/test_backbone_contract.py checks it).

    Construction: ``cls(cfg, scene=scene, act=act)``: ``cfg`` the validated ``Config``, ``scene`` the
    :class:`~arcsem.scene.Scene` at the training resolution, ``act`` the ACT module (stage 1 with ACT) or None.

    Before a run trains anything, its stage checks call the classmethods :meth:`check_config` (the validated
    ``Config`` and the device) and, once the scene is read, :meth:`check_scene`: once each per run.

    The trainer, per step: :meth:`learning_rates` (once) and the optimisers from :meth:`make_optimizers` (once,
    Adam for the groups it leaves out), :meth:`render` / :meth:`render_rays`, the losses, :meth:`pre_backward`,
    ``backward``, :meth:`post_backward`, the optimiser steps; :meth:`state_dict` / ``load_state_dict`` for
    checkpoints; :meth:`num_primitives` for the record; :meth:`export` at the end. Stage 2 calls
    :meth:`set_act` (None: no ACT when colouring), :meth:`param_groups` ``("color")``, :meth:`render`
    (its ``depth`` / ``median_depth`` for pseudo-colours) and :meth:`colour_operator` (per training view).
    """

    name: ClassVar[str]
    provides: ClassVar[frozenset[str]] = frozenset({"rgb", "alpha", "depth"})
    batch_mode: ClassVar[Literal["image", "rays"]] = "image"
    export_suffix: ClassVar[str] = ".ply"  # the file :meth:`export` writes: model<suffix> in the run folder
    rays_per_step: ClassVar[int] = 5000  # ray backbones: rays per training step unless train.rays_per_batch is set

    @dataclass
    class Config:
        pass

    def __init__(self, cfg: Any, scene: Any = None, **runtime: Any):
        super().__init__()
        self.cfg = cfg

    @classmethod
    def check_config(cls, cfg: Any, device: str) -> None:
        """Before a run reads any data: what this plugin needs beyond its ``Config``'s field rules, for ``cfg`` (the
        validated ``Config``) on ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``): an optional dependency, a device.
        Raise :class:`~arcsem.errors.ConfigError` / ``PluginError`` naming the key and the fix. Called once per run,
        by the checks of the stages that build this backbone (:mod:`arcsem.stages`). Default: nothing to check."""

    @classmethod
    def check_scene(cls, cfg: Any, scene: Any) -> None:
        """Once the scene is read, before training: what this plugin needs of it with ``cfg`` (the validated
        ``Config``): camera models (``scene.train.cameras.model``), image sizes ``[H, W]``... Raise ConfigError
        naming the key and the fix. Called once per run, like :meth:`check_config`. Default: nothing to check."""

    def render(self, cams: Cameras, **kw: Any) -> RenderOutput:
        """Render ``C`` cameras; returns at least the keys in ``provides`` (``[C, H, W, k]`` each)."""
        raise NotImplementedError

    def colour_operator(self, cams: Cameras) -> Callable[[], RenderOutput] | None:
        """Stage 2, geometry frozen: a function rendering ``cams`` (one view) as :meth:`render` does for as long as
        the geometry stays as it is, cheaper (e.g. recorded compositing weights) and differentiable in the colour
        parameters, with an ``nbytes`` attribute (the memory it holds; ``colorize.frozen_mb`` budgets them).
        Default None: stage 2 calls :meth:`render`."""
        return None

    def render_rays(self, rays_o: Tensor, rays_d: Tensor, image_ids: Tensor, **kw: Any) -> RenderOutput:
        """Ray backbones: render ``[R, 3]`` rays (directions with unit camera z); ``image_ids [R]`` select ACT."""
        raise NotImplementedError(f"{self.name} renders whole images only")

    def param_groups(self, stage: str) -> dict[str, list[nn.Parameter]]:
        """Parameters by optimiser group; ``stage`` is ``"geometry"`` (stage 1) or ``"color"`` (stage 2, colours only)."""
        raise NotImplementedError

    def learning_rates(self, stage: str) -> dict[str, GroupSchedule | Callable[[int], float]]:
        """The rate of each group of :meth:`param_groups` ``(stage)``: a :class:`~arcsem.configs.GroupSchedule`
        (constant, or log-linear decay) or a function ``step -> lr``. ``train.optim.groups.<group>`` overrides it.

        Default: from the ``Config`` fields ``lr_<group>`` (and ``lr_<group>_final``: a log-linear decay over the
        run). A group without a rate stops the run before it trains, naming the group."""
        out: dict[str, GroupSchedule | Callable[[int], float]] = {}
        for group in self.param_groups(stage):
            lr = getattr(self.cfg, f"lr_{group}", None)
            if lr is not None:
                out[group] = GroupSchedule(lr=float(lr), lr_final=getattr(self.cfg, f"lr_{group}_final", None))
        return out

    def make_optimizers(self, stage: str, groups: dict[str, list[nn.Parameter]]) -> dict[str, torch.optim.Optimizer]:
        """Optimisers for some of ``groups`` (``{group: optimizer}``, one param group each, named ``group``);
        the trainer builds Adam (``train.optim``) for the rest. Default: none (all Adam). Not used when
        ``train.optim.type`` is set."""
        return {}

    def set_act(self, act: nn.Module | None) -> None:
        """Use ``act`` (an :class:`~arcsem.act.ACT`) on the colours, or none (stage 2 colours without ACT)."""
        self.act = act

    def pre_backward(self, step: int, out: RenderOutput) -> None:
        """Hook before ``loss.backward()`` (e.g. retain gradients of screen-space means)."""

    def post_backward(self, step: int, out: RenderOutput, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        """Hook after backward, before the optimiser step (densify, prune, upsample); may replace the tensors of
        ``optimizers[group]`` (and their state)."""

    def num_primitives(self) -> int:
        """Gaussians, voxels...: the model's size for the record (default: the number of parameters)."""
        return sum(p.numel() for p in self.parameters())

    def export(self, path: str) -> None:
        """Write the model in a format other tools read, to ``path`` (ends with :attr:`export_suffix`).
        Default: nothing to export (``NotImplementedError``; the run goes on)."""
        raise NotImplementedError

    def export_viewer(self, folder: str, cams: Cameras, names: list[str], centre: Tensor,
                      iteration: int) -> dict[str, str]:
        """Write the folder layout that common 3DGS viewers load (``point_cloud/iteration_N/point_cloud.ply``
        and ``cameras.json`` of ``cams`` named ``names``); returns the paths. Gaussians only."""
        raise NotImplementedError(f"{self.name}: no viewer export")


class Loss(nn.Module):
    """Base class of loss terms: :meth:`forward` returns an unweighted scalar; the trainer weights it.

    Declared for the trainer (:func:`arcsem.train.losses.build_losses` checks them before any work): ``requires``,
    the render outputs it reads (checked against the backbone's ``provides``); ``batch_modes``, the batches it
    works on (``"image"``: whole views ``[C, H, W, 3]``, ``"rays"``: ``[R, 3]``); ``Config`` with ``weight`` and
    ``start_step`` (0-based step from which it counts); ``needs``, the optional parts of the :class:`Batch` it
    reads (``"color"``: the stage-2 :class:`ColorTargets`, so it can only be a term of ``colorize.losses``).
    Construction: ``cls(cfg, **runtime)`` (stage 1 passes ``backbone=<name>`` and ``act``).
    """

    name: ClassVar[str]
    requires: ClassVar[frozenset[str]] = frozenset({"rgb"})
    batch_modes: ClassVar[frozenset[str]] = frozenset({"image", "rays"})
    needs: ClassVar[frozenset[str]] = frozenset()

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0

    def __init__(self, cfg: Any, **runtime: Any):
        super().__init__()
        self.cfg = cfg

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        """The unweighted loss of render ``out`` on ``batch`` at 0-based ``step``: a scalar tensor."""
        raise NotImplementedError
