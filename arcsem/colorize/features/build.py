"""``build_extractor``: the one place that knows every TCM/CCM feature extractor (:mod:`.base` names them).

It sits above the extractors' modules (:mod:`..vgg`, :mod:`.daisy`, :mod:`.learned`), which build on
:mod:`.base`; heavy modules import when their extractor is asked for.
"""
from __future__ import annotations

from ...configs import VGG_FEATURES
from .base import FEATURES, Extractor, SceneContext, resolve_features

__all__ = ["build_extractor"]


def build_extractor(name: str, ctx: SceneContext | None = None) -> Extractor:
    """The extractor ``name`` (``auto`` resolved); ``learned`` is trained on ``ctx`` (or read from its cache)."""
    from ...errors import ConfigError

    name = resolve_features(name)
    if name in VGG_FEATURES:
        import copy

        from ..vgg import get_vgg

        return copy.deepcopy(get_vgg(name))  # the run's own, free to move to its device; the weights load once
    if name == "daisy":
        from .daisy import DaisyFeatures

        return DaisyFeatures()
    if name == "learned":
        from .learned import learned_extractor

        if ctx is None:
            raise ConfigError("colorize.features=learned needs the scene (grey views, stage-1 depth, cameras)")
        return learned_extractor(ctx)
    raise ConfigError(f"colorize.features: unknown extractor '{name}'; available: {', '.join(FEATURES)}")
