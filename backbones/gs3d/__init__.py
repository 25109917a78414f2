"""3D Gaussian Splatting backbone (``gs3d``); importing registers it."""
from .backbone import GS3DBackbone

__all__ = ["GS3DBackbone"]
