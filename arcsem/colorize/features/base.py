"""The feature-extractor interface of TCM/CCM matching, the colour loss space, and ``colorize.features=auto``.

An extractor maps grey images ``[N, H, W, 3]`` in [0, 1] (three equal channels) to per-block feature
maps ``[N, D_b, H // s_b, W // s_b]`` for its block strides ``s_b`` (VGG: relu3_x at 4 and relu4_x at
8); TCM matches every block location of a grey view to the nearest location (cosine) of the grey
references, CCM does the same on block 0 pooled to its cells. Extractors:

* ``vgg16`` / ``vgg19``: torchvision VGG with ImageNet weights from the torch hub cache (Ref-NPR /
  the ArCSEM code); random weights where they cannot be had (recorded as ``vgg16-random``);
* ``daisy``: dense DAISY descriptors (OpenCV contrib), :mod:`.daisy`;
* ``learned``: a small CNN trained on the scene's grey training views, positives given by the
  stage-1 depth and cameras, :mod:`.learned`.

TCM's loss compares the render with the guidance in a *loss space*: the extractor's own features
(VGG, the paper) or ``color``: the image averaged over each block cell, compared by ``1 - cos``, so
the matched reference colour's chromaticity is copied and the render keeps its own brightness
(the stage-1 shading). DAISY and the learned CNN describe grey structure and cannot be applied to a
colour render, so they use ``color``.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
import torch.nn.functional as F
from torch import Tensor

from ...configs import EXTRACTORS, VGG_FEATURES

__all__ = ["DEFAULT_WITHOUT_IMAGENET", "FEATURES", "ColourSpace", "Extractor", "SceneContext", "announce_features",
           "check_features", "grey_channel", "imagenet_vgg_available", "no_grad_features", "resolve_features",
           "space_label", "tcm_space"]

log = logging.getLogger(__name__)

FEATURES = ("auto", *EXTRACTORS)
# The extractor `auto` takes where no ImageNet VGG weights exist: the best measured without them, end to end
# (held-out colour PSNR of the full method at one reference, three seeds, two scenes, paired by seed:
# benchmarks/results/features/README.md, section 5): VGG16 with random weights, ahead of DAISY and the
# scene-trained CNN (`learned`), whose lower matching error (section 1) did not carry over to the colours.
DEFAULT_WITHOUT_IMAGENET = "vgg16"


class Extractor(Protocol):
    """What TCM/CCM need of a feature extractor (see the module docstring)."""

    name: str                  # "vgg16", "daisy", "learned", ...
    strides: tuple[int, ...]   # block strides in pixels of the input image
    differentiable: bool       # usable on a colour render as the TCM loss space

    def key(self) -> str: ...                                  # identity for caches (changes with weights)
    def label(self) -> str: ...                                # recorded as ``features`` (e.g. vgg16-random)
    def __call__(self, images: Tensor) -> list[Tensor]: ...    # [N,H,W,3] -> [[N,D_b,H//s_b,W//s_b]]


@dataclass
class SceneContext:
    """What an extractor trained on the scene needs (at the colourisation resolution).

    gray: ``[N, H, W, 3]`` grey training views. cameras: their ``N`` cameras. masks: ``[N, H, W]`` bool.
    depths: returns ``[N, H, W]`` z-depth (0 = none), called only when a model must be trained.
    depth_key: what the depths are (hash of the stage-1 checkpoint or of the depth maps).
    """

    gray: Tensor
    cameras: Any
    masks: Tensor
    depths: Callable[[], Tensor]
    depth_key: str
    seed: int = 0
    downscale: int = 4
    cache_dir: Path | None = None
    progress: bool = False


class ColourSpace:
    """TCM loss space ``color``: ``images [C, H, W, 3]`` -> per block ``[C, 3, H // s, W // s]`` cell means."""

    name = "color"

    def __init__(self, strides: tuple[int, ...]):
        self.strides = tuple(strides)

    def __call__(self, images: Tensor) -> list[Tensor]:
        x = images.permute(0, 3, 1, 2)
        return [F.avg_pool2d(x, s) for s in self.strides]


def space_label(space) -> str:
    """``color`` for a :class:`ColourSpace`, else ``features`` (the extractor itself)."""
    return "color" if isinstance(space, ColourSpace) else "features"


def imagenet_vgg_available(arch: str = "vgg16") -> bool:
    """Whether the ImageNet weights of ``arch`` are in the torch hub cache (nothing is downloaded)."""
    from ...weights import find_hub_weights
    from ..vgg import WEIGHT_FILES

    return find_hub_weights(WEIGHT_FILES[arch]) is not None


def resolve_features(name: str) -> str:
    """``auto`` -> ``vgg16`` where its ImageNet weights are in the hub cache, else the measured best
    (:data:`DEFAULT_WITHOUT_IMAGENET`); other names are returned unchanged. Says nothing: see :func:`announce_features`."""
    if name != "auto":
        return name
    return "vgg16" if imagenet_vgg_available("vgg16") else DEFAULT_WITHOUT_IMAGENET


def announce_features(name: str) -> str:
    """:func:`resolve_features`, logging what ``auto`` chose and why. The job's config check calls it (once per
    job, so each job's log says what it used); :func:`.build.build_extractor` resolves silently."""
    chosen = resolve_features(name)
    if name == "auto":
        if imagenet_vgg_available("vgg16"):
            why = "ImageNet VGG16 weights found"
        else:
            what = "with random weights, " if chosen in VGG_FEATURES else ""
            why = (f"no ImageNet VGG weights in the torch hub cache; {what}the best extractor measured without "
                   "them (benchmarks/results/features)")
        log.warning("colorize.features=auto: TCM/CCM use '%s' features (%s)", chosen, why)
    return chosen


def _check_space(choice: str, name: str, differentiable: bool) -> None:
    """``colorize.tcm_space=features`` needs features that can be computed on a colour render (VGG's)."""
    from ...errors import ConfigError

    if choice == "features" and not differentiable:
        raise ConfigError(f"colorize.tcm_space=features: '{name}' features cannot be computed on a "
                          "colour render; use tcm_space=color (or auto)")


def check_features(name: str, space: str) -> str:
    """Before a run: the extractor ``name`` (``auto`` announced: :func:`announce_features`) can run here, and the
    TCM loss space ``space`` suits it. Returns the extractor's name."""
    chosen = announce_features(name)  # the one line per job that says what `auto` chose
    if chosen == "daisy":
        from .daisy import require_daisy

        require_daisy()
    _check_space(space, chosen, chosen in VGG_FEATURES)
    return chosen


def tcm_space(choice: str, extractor: Extractor):
    """The TCM loss space: ``auto`` = the extractor's own features where it is differentiable (VGG), else colour."""
    _check_space(choice, extractor.name, extractor.differentiable)
    if choice == "features" or (choice == "auto" and extractor.differentiable):
        return extractor
    return ColourSpace(extractor.strides)


def grey_channel(images: Tensor) -> Tensor:
    """``[N, H, W, 3]`` -> ``[N, 1, H, W]`` channel mean, each image standardised (exposure-drift invariant)."""
    g = images.float().mean(-1, keepdim=True).permute(0, 3, 1, 2)
    mu = g.mean(dim=(2, 3), keepdim=True)
    sd = g.std(dim=(2, 3), keepdim=True).clamp_min(1e-3)
    return (g - mu) / sd


def no_grad_features(extractor: Extractor, images: Tensor, batch: int = 4) -> list[Tensor]:
    """``extractor(images)`` without gradients, ``batch`` images at a time, blocks concatenated."""
    parts: list[list[Tensor]] = []
    with torch.no_grad():
        for s in range(0, len(images), batch):
            parts.append(extractor(images[s:s + batch]))
    return [torch.cat([p[b] for p in parts]) for b in range(len(parts[0]))]
