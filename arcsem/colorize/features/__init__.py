"""Feature extractors for TCM/CCM matching (``colorize.features``): VGG, dense DAISY, a scene-trained CNN.

See :mod:`.base` for the interface and the TCM loss spaces. Heavy modules import lazily.
"""
from .base import (
    DEFAULT_WITHOUT_IMAGENET,
    FEATURES,
    ColourSpace,
    Extractor,
    SceneContext,
    announce_features,
    check_features,
    resolve_features,
    tcm_space,
)
from .build import build_extractor

__all__ = ["DEFAULT_WITHOUT_IMAGENET", "FEATURES", "ColourSpace", "Extractor", "SceneContext", "announce_features",
           "build_extractor", "check_features", "resolve_features", "tcm_space"]
