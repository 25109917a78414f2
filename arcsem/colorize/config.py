"""``colorize``: the stage-2 preset (conf/colorize/quick.yaml and paper.yaml are validated against it)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..registry import checked
from ..train.optim import OptimConfig
from ..train.stage1 import EvalConfig

__all__ = ["DEFAULT_LOSSES", "ColorizeConfig"]

DEFAULT_LOSSES = {
    "reference_l1": {"weight": 20.0},  # reference views: 20 x L1 (paper)
    "pseudo_color": {"weight": 1.0},  # lambda_pc
    "tcm": {"weight": 1.0},  # lambda_tcm = 1 (paper)
    # lambda_cc: the paper describes CCM as used, the ArCSEM command line set it to 0; Ref-NPR uses 5.
    # Default on (the paper's choice) with Ref-NPR's weight; `colorize.losses.ccm.weight=0` = the code's.
    "ccm": {"weight": 5.0},
}


@dataclass
class ColorizeConfig:
    steps: int = checked(20_000, ge=1)  # ArCSEM stage 2
    references: Any = "five"  # preset (five|four|three|two|one) or image file(s)/folder matched by file stem
    stage1: str | None = None  # stage-1 run folder or checkpoint; default: this run's, then the shared cache
    masks: str = checked("auto", choices=("auto", "dataset", "files", "otsu", "grabcut", "sam", "none"))  # auto (dataset masks, else otsu) | dataset | files | otsu | grabcut | sam | none
    mask_folder: str | None = None  # masks=files: folder of <view name>.<ext>
    sam_checkpoint: str | None = None  # masks=sam: Segment Anything checkpoint
    depth: str = checked("model", choices=("model", "dataset"))  # depth for pseudo-colours: model (stage-1 render, the paper) | dataset (ground truth)
    radius: float | None = checked(None, gt=0.0)  # fixed world search radius; None: radius_factor x pixel footprint
    radius_factor: float = checked(2.0, gt=0.0)  # radius in pixel footprints (ortho 1/fx, pinhole z/fx) at the query's depth
    # TCM/CCM matching features (arcsem.colorize.features): vgg16 (Ref-NPR) | vgg19 (ArCSEM code), ImageNet weights
    # from the torch hub cache | daisy (dense DAISY, OpenCV) | learned (a CNN trained on the scene's grey views with
    # stage-1 correspondences) | auto: vgg16 where its ImageNet weights exist, else the best measured without them
    features: str = checked("auto", choices=("auto", "vgg16", "vgg19", "daisy", "learned"))
    # TCM loss space: features (the extractor's own, VGG only: the paper) | color (cell-mean colour, 1 - cos) |
    # auto: features for VGG, color for daisy/learned (they cannot describe a colour render)
    tcm_space: str = checked("auto", choices=("auto", "features", "color"))
    tcm_downscale: int = checked(4, ge=1)  # TCM/CCM on images scaled down by 4 (paper)
    ccm_downscale: int = checked(16, ge=1)  # CCM cell size in pixels (Ref-NPR)
    ccm_max_dist: float = checked(0.6, ge=0.0, le=2.0)  # CCM accepts a match if its cosine distance <= this (Ref-NPR)
    ccm_white: float = checked(0.99, ge=0.0, le=1.0)  # CCM ignores reference cells whose mean is above this in every channel (Ref-NPR)
    downscale: float = checked(1.0, ge=1.0)  # training resolution; 1.0 and width None: stage 1's resolution
    width: int | None = checked(None, ge=1)
    batch_views: int = checked(1, ge=1)
    log_every: int = checked(100, ge=1)
    checkpoint_every: int = checked(5000, ge=0)
    resume: str = checked("auto", choices=("auto", "never", "must"))
    progress: bool = True
    cache_dir: str | None = None  # pseudo-colour/guidance cache; default <arcsem cache root>/colorize
    losses: dict[str, Any] = field(default_factory=lambda: {k: dict(v) for k, v in DEFAULT_LOSSES.items()})
    optim: OptimConfig = field(default_factory=OptimConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
