"""The shared Gaussian settings (3DGS and 2DGS): a plain dataclass, importable without torch (Hydra schema)."""
from __future__ import annotations

from dataclasses import dataclass, field

from arcsem.registry import checked

__all__ = ["LOWPASS_SIGMA", "GaussianConfig"]

LOWPASS_SIGMA = 2**-0.5
"""The official 2DGS screen-space low-pass sigma, in pixels (``rho2d = |pixel - centre|^2 / sigma^2 = 2 |d|^2``; the
kernels take ``1 / sigma^2``, so a sigma must be > 0). gsplat's 2DGS compiles this one in. The one place it is
written: the gs2d ``Config`` default, the rasterisers' defaults and the gsplat check read it from here."""


@dataclass
class GaussianConfig:
    """Shared Gaussian settings; defaults = the official 3DGS/2DGS ones."""

    sh_degree: int = checked(3, ge=0, le=3)  # maximum SH degree
    sh_increase_every: int = checked(1000, ge=1)  # active SH degree +1 every this many steps (stage 1)
    random_init_points: int = checked(100_000, ge=1)  # random init inside the scene bounds when there is no point cloud
    init_opacity: float = checked(0.1, gt=0.0, le=1.0)  # initial opacity of every Gaussian
    background: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # RGB behind the scene
    # learning rates (Adam); position is multiplied by the scene extent and decays log-linearly
    lr_position_init: float = checked(1.6e-4, ge=0.0)
    lr_position_final: float = checked(1.6e-6, ge=0.0)
    lr_position_max_steps: int = checked(30_000, ge=1)
    lr_feature: float = checked(2.5e-3, ge=0.0)  # SH DC
    lr_feature_rest: float = checked(2.5e-3 / 20, ge=0.0)  # higher SH bands
    lr_opacity: float = checked(0.05, ge=0.0)
    lr_scaling: float = checked(0.005, ge=0.0)
    lr_rotation: float = checked(0.001, ge=0.0)
    # adaptive density control
    densify: bool = True
    densify_from: int = checked(500, ge=0)
    densify_until: int = checked(15_000, ge=0)
    densify_every: int = checked(100, ge=1)
    densify_grad_threshold: float = checked(2e-4, gt=0.0)  # mean NDC gradient norm (see densify.py)
    percent_dense: float = checked(0.01, gt=0.0)  # clone if max scale <= this x extent, else split
    opacity_reset_every: int = checked(3000, ge=1)  # opacities -> min(o, 0.01)
    prune_opacity: float = checked(0.05, ge=0.0, le=1.0)  # 2DGS 0.05, 3DGS 0.005
    max_screen_size: float = checked(20.0, gt=0.0)  # prune screen radius > this (px) after the first opacity reset
    max_world_scale: float = checked(0.1, gt=0.0)  # ... and max scale > this x extent
    # rasteriser
    tile: int = checked(16, ge=1)
    chunk_tiles: int | None = checked(None, ge=1)  # tiles composited at once (None = renderer's default)
    # auto: fused C++ kernels when they build (CPU); on CUDA (8.0+) the Triton kernels for 2DGS where Triton imports; else
    # the PyTorch reference (one warning); torch | cpp explicit;
    # gsplat: gsplat's CUDA rasterisers (optional: pip install gsplat, device=cuda; backbones/gaussians/gsplat_bridge.py);
    # triton: 2DGS only, projection, footprints and compositing as Triton kernels (CUDA; backbones/gaussians/triton2d.py)
    rasterizer: str = checked("auto", choices=("auto", "torch", "cpp", "gsplat", "triton"))
