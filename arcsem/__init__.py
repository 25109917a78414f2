"""arcsem: colourising 3-D scenes of SEM images (ArCSEM), as a plugin-based experiment framework.

The public names below are imported lazily (PEP 562), so ``import arcsem`` and the console scripts
start without importing torch until something needs it.
"""
from __future__ import annotations

import importlib

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


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module 'arcsem' has no attribute '{name}'")
