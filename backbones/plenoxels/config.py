"""``plenoxels`` settings: a plain dataclass, importable without torch (Hydra schema, :mod:`arcsem.schemas`).

Defaults are the paper's (ArCSEM: 128^3 growing to 304x304x128, 38,400 steps per resolution) and svox2's."""
from __future__ import annotations

from dataclasses import dataclass, field

from arcsem.registry import checked

__all__ = ["PlenoxelsConfig"]


@dataclass
class PlenoxelsConfig:
    reso: list[list[int]] = field(default_factory=lambda: [[128, 128, 128], [256, 256, 128], [304, 304, 128]])
    """Grid resolutions of the coarse-to-fine schedule. Paper: 128^3 up to 304x304x128 in 3 stages
    (115,200 steps = 3 x 38,400); the middle resolution is not given in the paper (our choice)."""
    upsample_every: int = checked(38400, ge=1)
    """Steps per resolution (paper: 38,400)."""
    sh_degree: int = checked(2, ge=0, le=3)
    """SH degree (svox2: 2, 9 coefficients per channel)."""
    init_sigma: float = 0.1
    """Initial density (svox2), in 1 / normalised length (the box's longest half-side = 1)."""
    init_points_sigma: float = 0.0
    """With a point cloud: the starting density of the voxels near its points (0: svox2's uniform start)."""
    init_points_dilate: int = checked(1, ge=0)
    """... within this many voxels of a point."""
    init_sh: float = 0.0
    """Initial SH coefficients (svox2: 0, i.e. grey 0.5)."""
    step_size: float = checked(0.5, gt=0.0)
    """Ray-marching step in voxels (svox2: 0.5)."""
    stop_thresh: float = checked(1e-4, ge=0.0, le=1.0)
    """Early stop: samples with transmittance below this are masked (svox2: 1e-4 ... 1e-7)."""
    background_model: str = checked("constant", choices=("constant", "plane", "msi"))
    """What rays leaving the grid's box see (:mod:`.background`): "constant" (svox2), "plane" (a textured
    SH plane under the specimen: the SEM stub; our extension), "msi" (svox2's multi-sphere image)."""
    background: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    """Constant background colour (SEM: black); with ``learn_background`` its initial value. The plane
    and the MSI show it where they have nothing."""
    learn_background: bool = False
    """Learn the constant (group ``background``, stage 1 only). SEM views show the substrate far outside
    the specimen's box (our extension)."""
    background_reso: int = checked(256, ge=2)
    """Texels per side of the plane's texture; the MSI's images are reso/2 x reso."""
    background_sh_degree: int = checked(1, ge=0, le=3)
    """SH degree of the plane's texels (view-dependent substrate brightness)."""
    background_layers: int = checked(16, ge=1)
    """Spheres of the MSI (svox2: 32-64; 1 = a single image sphere)."""
    msi_far: float = checked(8.0, gt=1.0)
    """Radius of the MSI's outer sphere, in box half-diagonals (the substrate that grazing SEM views see
    lies many specimen sizes behind it)."""
    lr_background: float = checked(1e-2, ge=0.0)
    """RMSProp rate of the background's parameters (constant logit, plane texture, MSI logits)."""
    batch_size: int = checked(5000, ge=1)
    """Rays per training step (svox2)."""
    optimizer: str = checked("rmsprop", choices=("rmsprop",))
    """svox2 uses RMSProp for density and SH."""
    rms_beta: float = checked(0.95, ge=0.0, le=1.0)
    rms_eps: float = checked(1e-8, gt=0.0)
    lr_sigma: float = checked(3e1, gt=0.0)
    lr_sigma_final: float = checked(5e-2, gt=0.0)
    lr_sigma_decay_steps: int = checked(250000, ge=0)
    """Steps of the log-linear decay to ``lr_sigma_final`` (svox2: 250,000; 0: the run's length)."""
    lr_sigma_delay_steps: int = checked(15000, ge=0)
    lr_sigma_delay_mult: float = checked(1e-2, ge=0.0, le=1.0)
    lr_sh: float = checked(1e-2, gt=0.0)
    lr_sh_final: float = checked(5e-6, gt=0.0)
    lr_sh_decay_steps: int = checked(250000, ge=0)
    """As ``lr_sigma_decay_steps`` (0: the run's length)."""
    lr_sh_delay_steps: int = checked(0, ge=0)
    lr_sh_delay_mult: float = checked(1e-2, ge=0.0, le=1.0)
    lambda_tv: float = checked(1e-5, ge=0.0)
    """TV weight on density (svox2 range 1e-5 .. 5e-3)."""
    lambda_tv_sh: float = checked(1e-3, ge=0.0)
    """TV weight on SH (svox2 range 1e-3 .. 5e-3)."""
    tv_sparse_frac: float = checked(0.01, gt=0.0, le=1.0)
    """Fraction of stored voxels on which TV is evaluated each step."""
    tv_eps: float = checked(1e-5, gt=0.0)
    prune: str = checked("weight", choices=("weight", "density", "none"))
    """After each upsample: "weight" (svox2: max rendering weight over training rays), "density", "none"."""
    prune_weight_thresh: float = checked(0.256, ge=0.0)
    """svox2: 0.0005 * 512, divided by the new z resolution."""
    prune_density_thresh: float = 5.0
    prune_dilate: int = checked(2, ge=0)
    prune_image_scale: float = checked(1.0, gt=0.0, le=1.0)
    """Scale of the training views rendered to find the max weights (svox2: full resolution) ..."""
    prune_max_rays: int = checked(1_000_000, ge=1)
    """... reduced further so that at most this many rays are rendered (CPU budget; our choice)."""
    chunk: int = checked(8192, ge=1)
    """Rays per chunk when rendering whole images."""
    rasterizer: str = checked("auto", choices=("auto", "torch", "cpp"))
    """"cpp" (fused C++ CPU kernel), "torch" (PyTorch reference, any device), "auto" (cpp on CPU if it builds)."""
