"""Stage 2, colourisation: references, masks, pseudo-colours, TCM/CCM guidance, frozen-geometry training.

Heavy modules import lazily: ``import arcsem.colorize`` does no work.
"""
from __future__ import annotations

from ..lazy import lazy_getattr

__all__ = [
    "ColorTargetHook",
    "ColorizeConfig",
    "Guidance",
    "References",
    "VGGFeatures",
    "build_extractor",
    "cached_pseudo_colors",
    "get_vgg",
    "load_references",
    "otsu_mask",
    "pseudo_colors",
    "run_stage2",
    "specimen_masks",
]

_WHERE = {
    "run_stage2": "stage2", "ColorTargetHook": "targets", "ColorizeConfig": "config",
    "load_references": "references", "References": "references",
    "specimen_masks": "masks", "otsu_mask": "masks",
    "pseudo_colors": "pseudocolor", "cached_pseudo_colors": "pseudocolor",
    "Guidance": "guidance", "VGGFeatures": "vgg", "get_vgg": "vgg", "build_extractor": "features",
}


__getattr__ = lazy_getattr(__name__, _WHERE)
