"""arcsem: colourising 3-D scenes of SEM images (ArCSEM), as a plugin-based experiment framework."""
from .cameras import Cameras
from .errors import ArcsemError, ConfigError, DataError, PluginError, TrainingError
from .plugins import BACKBONES, LOSSES, Backbone, Batch, Loss, RenderOutput
from .scene import Scene, Split

__all__ = [
    "Cameras", "Scene", "Split", "Backbone", "Loss", "Batch", "RenderOutput", "BACKBONES", "LOSSES",
    "ArcsemError", "ConfigError", "DataError", "PluginError", "TrainingError",
]
__version__ = "0.1.0"
