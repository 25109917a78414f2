"""arcsem: colourising 3-D scenes of SEM images (ArCSEM), as a plugin-based experiment framework.

The public names below are imported lazily (PEP 562), so ``import arcsem`` and the console scripts
start without importing torch until something needs it.
"""
from __future__ import annotations

from .lazy import lazy_getattr

__all__ = [
    "BACKBONES",
    "LOSSES",
    "ArcsemError",
    "Backbone",
    "Batch",
    "Cameras",
    "ConfigError",
    "DataError",
    "Interrupted",
    "Loss",
    "OutputError",
    "PluginError",
    "RenderOutput",
    "Scene",
    "Split",
    "TrainingError",
]
__version__ = "0.2.0"

_WHERE = {
    "Cameras": "cameras", "Scene": "scene", "Split": "scene",
    "Backbone": "plugins", "Loss": "plugins", "Batch": "plugins", "RenderOutput": "plugins",
    "BACKBONES": "plugins", "LOSSES": "plugins",
    "ArcsemError": "errors", "ConfigError": "errors", "DataError": "errors", "PluginError": "errors",
    "TrainingError": "errors", "OutputError": "errors", "Interrupted": "errors",
}


__getattr__ = lazy_getattr(__name__, _WHERE)
