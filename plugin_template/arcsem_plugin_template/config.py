"""The ``constant`` backbone's settings: a plain dataclass, importable without torch.

arcsem reads it as the package's ``CONFIG`` (entry point ``arcsem.backbones``) and stores it as the Hydra schema
of ``conf/backbone/constant.yaml`` at start-up, so ``backbone.value=0.25`` works without ``+`` and a mistyped key
fails at once."""
from __future__ import annotations

from dataclasses import dataclass

from arcsem.registry import checked

__all__ = ["ConstantConfig"]


@dataclass
class ConstantConfig:
    value: float = checked(0.5, ge=0.0, le=1.0)  # initial grey level
    depth: float = checked(1.0, gt=0.0)  # z-depth reported for every pixel
    lr: float = checked(1e-2, gt=0.0)  # learning rate of the colour (read by ConstantBackbone.learning_rates)
