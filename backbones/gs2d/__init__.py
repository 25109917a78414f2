"""2D Gaussian Splatting backbone (``gs2d``); importing registers it."""
from .backbone import GS2DBackbone

__all__ = ["GS2DBackbone"]
