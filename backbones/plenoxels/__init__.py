"""Plenoxels backbone: sparse SH voxel grid, ray marching, coarse-to-fine (svox2 in PyTorch, CPU/GPU)."""
from .backbone import Plenoxels, expon_lr

__all__ = ["Plenoxels", "expon_lr"]
