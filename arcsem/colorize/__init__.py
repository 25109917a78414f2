"""Stage 2, colourisation: references, masks, pseudo-colours, TCM/CCM guidance, frozen-geometry training.

Heavy modules import lazily: ``import arcsem.colorize`` does no work.
"""
from __future__ import annotations

__all__ = [
    "ColorTargets",
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
    "run_stage2": "stage2", "ColorTargets": "stage2", "ColorizeConfig": "config",
    "load_references": "references", "References": "references",
    "specimen_masks": "masks", "otsu_mask": "masks",
    "pseudo_colors": "pseudocolor", "cached_pseudo_colors": "pseudocolor",
    "Guidance": "guidance", "VGGFeatures": "vgg", "get_vgg": "vgg", "build_extractor": "features",
}


def __getattr__(name: str):
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module 'arcsem.colorize' has no attribute '{name}'")
