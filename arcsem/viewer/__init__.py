"""``arcsem-view``: a browser viewer of a trained run (viser + arcsem's CPU rasteriser)."""
from .server import MODES, Viewer, ViewerConfig, render_mode

__all__ = ["MODES", "Viewer", "ViewerConfig", "render_mode"]
