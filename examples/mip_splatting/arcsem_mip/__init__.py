"""3DGS with Mip-Splatting's 3-D smoothing filter (Yu et al., CVPR 2024) as an arcsem backbone plugin.

The entry point ``arcsem.backbones: gs3d_mip = "arcsem_mip"`` names this package: arcsem reads ``CONFIG`` (light,
no torch: the Hydra schema of ``backbone/gs3d_mip.yaml``) at start-up and ``BACKBONE`` (the class, imported here
only when first read) when ``backbone=gs3d_mip`` is used."""
from arcsem.lazy import lazy_getattr

__all__ = ["BACKBONE", "CONFIG"]

__getattr__ = lazy_getattr(__name__, {"CONFIG": "config:MipConfig", "BACKBONE": "backbone:MipGS3D"})
