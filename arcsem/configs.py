"""The config dataclasses of arcsem's core: the schemas of ``conf/`` (``train``, ``colorize``, ``act``, ``mesh``,
``render``) and the dataset reader options. Plain dataclasses with :func:`~arcsem.registry.checked` rules (and, where a
rule spans fields, a ``check()`` method), no torch: the CLI registers them in Hydra's ConfigStore at start-up
(:mod:`arcsem.schemas`), and a run validates each group once (:class:`arcsem.runconfig.RunConfig`). Defaults are the
paper's and live here only; ``conf/*/*.yaml`` list only what a preset changes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .errors import ConfigError
from .registry import checked

__all__ = [
    "ACT_MODES",
    "DEFAULT_LOSSES",
    "EXTRACTORS",
    "MESH_FORMATS",
    "RENDER_LAYERS",
    "SPLIT_MODES",
    "VGG_FEATURES",
    "ActConfig",
    "ColorizeConfig",
    "EvalConfig",
    "GroupSchedule",
    "GuardConfig",
    "MeshConfig",
    "OptimConfig",
    "ReaderOptions",
    "RenderConfig",
    "SurfaceConfig",
    "TrainConfig",
]

ACT_MODES = ("rgb", "scalar")
VGG_FEATURES = ("vgg16", "vgg19")
"""The extractors whose features can be computed on a colour render (``colorize.tcm_space=features``)."""
EXTRACTORS = (*VGG_FEATURES, "daisy", "learned")
"""The TCM/CCM feature extractors (:mod:`arcsem.colorize.features`); ``colorize.features`` also takes ``auto``."""
SPLIT_MODES = ("auto", "every_k", "holdout", "none")


@dataclass
class GroupSchedule:
    """Learning rate of one group over the run (log-linear decay, as in 3DGS/svox2)."""

    lr: float = checked(ge=0.0)  # rate at step 0
    lr_final: float | None = checked(None, ge=0.0)  # rate at ``decay_steps`` (None: constant)
    decay_steps: int | None = checked(None, ge=1)  # steps of the decay (None: the run's length)
    delay_steps: int = checked(0, ge=0)  # svox2-style warm-up: rate multiplied by a sine ramp from ``delay_mult`` to 1
    delay_mult: float = checked(1.0, ge=0.0)


@dataclass
class OptimConfig:
    """``train.optim``: optimiser type, its constants and per-group overrides."""

    type: str | None = checked(None, choices=("adam", "rmsprop"))  # None: the backbone's choice, else adam
    eps: float = checked(1.0e-15, gt=0.0)  # Adam epsilon of 3DGS/2DGS
    betas: tuple[float, float] = (0.9, 0.999)
    rmsprop_alpha: float = checked(0.95, ge=0.0, le=1.0)  # svox2's RMSProp beta
    rmsprop_eps: float = checked(1.0e-8, gt=0.0)
    groups: dict[str, Any] = field(default_factory=dict)  # group -> GroupSchedule overrides
    lr_scale: float = checked(1.0, gt=0.0)  # every group's rate (not ACT's) times this: short schedules take larger steps
    fused: bool = True  # Adam's fused kernel (one pass over a parameter; 7x PyTorch's loop on the CPU, measured)


@dataclass
class EvalConfig:
    """``train.eval``: what the final and periodic evaluations do."""

    metrics: str = checked("3dgs", choices=("3dgs", "skimage"))  # the metric convention (arcsem/metrics.py):
    # 3dgs = the 3DGS/2DGS evaluation scripts the paper used (8-bit render, zero-padded SSIM, LPIPS-VGG);
    # skimage = float render, scikit-image SSIM, LPIPS-AlexNet
    lpips: bool = True  # LPIPS (the convention's network); NaN + reason when its ImageNet weights are missing
    # views LPIPS scores: all (every evaluated view, the paper) | test (held-out views only: LPIPS-VGG is most of an
    # evaluation's time on the CPU; the training views' LPIPS is then NaN)
    lpips_splits: str = checked("all", choices=("all", "test"))
    renders: bool = True  # write renders/{train,test}/<name>.png and <name>_depth.png
    video: bool = True  # turntable.mp4: novel views on a full orbit around the specimen
    video_frames: int = checked(60, ge=1)
    fps: int = checked(20, ge=1)
    max_train_views: int | None = checked(None, ge=1)  # score at most this many training views (None: all, the paper)
    periodic_views: int = checked(4, ge=1)  # views scored (PSNR/SSIM) at every periodic evaluation


@dataclass
class TrainConfig:
    """``train``: the stage-1 preset (see conf/train/quick.yaml and paper.yaml)."""

    steps: int = checked(60_000, ge=1)  # ArCSEM stage 1
    batch_views: int = checked(1, ge=1)  # views per step (image backbones)
    rays_per_batch: int | None = checked(None, ge=1)  # ray backbones; None: the backbone's batch_size, else 5000
    downscale: float = checked(1.0, ge=1.0)  # training/evaluation images at 1/downscale of the dataset resolution
    width: int | None = checked(None, ge=1)  # or: resize to this width (overrides downscale; never upsamples)
    log_every: int = checked(100, ge=1)
    eval_every: int = checked(0, ge=0)  # periodic evaluation (0: only the final one)
    checkpoint_every: int = checked(5000, ge=0)  # 0: only at the end
    resume: str = checked("auto", choices=("auto", "never", "must"))
    progress: bool = True
    losses: dict[str, Any] = field(default_factory=lambda: {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}})
    optim: OptimConfig = field(default_factory=OptimConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)


@dataclass
class ActConfig:
    """``act`` (conf/act/*.yaml): whether and how stage 1 learns per-image affine colour transforms."""

    enabled: bool = False
    mode: str = checked("rgb", choices=ACT_MODES)  # rgb: the paper's text; scalar: the authors' code
    lr: float = checked(1e-4, ge=0.0)  # constant Adam rate of the transforms (0: held where they start)
    init_noise: float = checked(1e-3, ge=0.0)  # identity + N(0, init_noise)


DEFAULT_LOSSES = {
    "reference_l1": {"weight": 20.0},  # reference views: 20 x L1 (paper)
    "pseudo_color": {"weight": 1.0},  # lambda_pc
    "tcm": {"weight": 1.0},  # lambda_tcm = 1 (paper)
    # lambda_cc: the paper describes CCM as used, the ArCSEM command line set it to 0; Ref-NPR uses 5.
    # Default on (the paper's choice) with Ref-NPR's weight; `colorize.losses.ccm.weight=0` = the code's.
    "ccm": {"weight": 5.0},
}


@dataclass
class GuardConfig:
    """``colorize.guard``: the confidence tests TCM and CCM matches must pass (:mod:`arcsem.colorize.guard`)."""

    enabled: bool = True  # false: every location keeps its nearest match (the paper, Ref-NPR)
    ratio: float = checked(0.9, gt=0.0, le=1.0)  # best distance <= ratio x the best non-neighbouring one
    exclude: int = checked(1, ge=0)  # cells around a match that count as its neighbours
    mutual: bool = True  # the match's own nearest view location must be the query (within exclude cells)
    normal_tol: float = checked(0.35, gt=0.0)  # largest difference of the normals' elevation n . u
    height_tol: float = checked(0.15, gt=0.0)  # largest difference of the heights (share of the specimen's)
    views_tol: float = checked(0.2, gt=0.0)  # largest difference from the other views' median colour at a point
    # TCM and CCM act only on the cells the pseudo-colour target leaves (under half their pixels have one): where the
    # stage-1 geometry already says which reference pixel a point shows, an appearance match is the weaker evidence
    uncovered_only: bool = True
    # where no validation decides (one reference, or validate=off): drop TCM / CCM when their kept matches, searched
    # away from each location's own surface point, bring colours no closer to the 2-D pseudo-colours than the guess
    # without them, on the cells those cover (arcsem.colorize.guard.match_check; the evidence with one reference)
    check: bool = True


@dataclass
class SurfaceConfig:
    """``colorize.surface``: reference colours spread over the stage-1 surface (:mod:`arcsem.colorize.surface`)."""

    # fill: the stage-2 pseudo-colour target takes the surface colour where the 2-D pseudo-colours have none |
    # off: 2-D pseudo-colours only (the paper)
    mode: str = checked("fill", choices=("fill", "off"))
    cell_px: float = checked(1.5, gt=0.0)  # node cell, in pixel footprints at the median depth
    k: int = checked(12, ge=1)  # neighbours per node
    reach: float = checked(3.0, gt=0.0)  # longest edge, in cells
    grey_scale: float = checked(0.05, gt=0.0)  # s_g of the grey term (grey in [0, 1])
    normal_scale: float = checked(0.25, gt=0.0)  # s_n of the normal term
    clusters: int = checked(6, ge=1)  # reference colour clusters for the confidence
    confidence: float = checked(0.6, gt=0.0, le=1.0)  # least probability of the best cluster


@dataclass
class ColorizeConfig:
    steps: int = checked(20_000, ge=1)  # ArCSEM stage 2
    references: Any = "five"  # preset (five|four|three|two|one: a bare word is always a preset) or image file(s)/
    # folder matched by file stem, written as a path (with / or .: ./one, refs/a.png)
    stage1: str | None = None  # stage-1 run folder or checkpoint; default: this run's, then the shared cache
    masks: str = checked("auto", choices=("auto", "dataset", "files", "otsu", "grabcut", "sam", "none"))  # auto (dataset masks, else otsu) | dataset | files | otsu | grabcut | sam | none
    mask_folder: str | None = None  # masks=files: folder of <view name>.<ext>
    sam_checkpoint: str | None = None  # masks=sam: Segment Anything checkpoint
    depth: str = checked("model", choices=("model", "dataset"))  # depth for pseudo-colours: model (stage-1 render, the paper) | dataset (ground truth)
    radius: float | None = checked(None, gt=0.0)  # fixed world search radius; None: radius_factor x pixel footprint
    radius_factor: float = checked(2.0, gt=0.0)  # radius in pixel footprints (ortho 1/fx, pinhole z/fx) at the query's depth
    # TCM/CCM matching features (arcsem.colorize.features): vgg16 (Ref-NPR) | vgg19 (ArCSEM code), ImageNet weights
    # from the torch hub cache | daisy (dense DAISY, OpenCV) | learned (a CNN trained on the scene's grey views with
    # stage-1 correspondences) | auto: vgg16 where its ImageNet weights exist, else the best measured without them
    features: str = checked("auto", choices=("auto", *EXTRACTORS))
    # TCM loss space: features (the extractor's own, VGG only: the paper) | color (cell-mean colour, 1 - cos) |
    # auto: features for VGG, color for daisy/learned (they cannot describe a colour render)
    tcm_space: str = checked("auto", choices=("auto", "features", "color"))
    tcm_downscale: int = checked(4, ge=1)  # TCM/CCM on images scaled down by 4 (paper)
    ccm_downscale: int = checked(16, ge=1)  # CCM cell size in pixels (Ref-NPR)
    ccm_max_dist: float = checked(0.6, ge=0.0, le=2.0)  # CCM accepts a match if its cosine distance <= this (Ref-NPR)
    ccm_white: float = checked(0.99, ge=0.0, le=1.0)  # CCM ignores reference cells whose mean is above this in every channel (Ref-NPR)
    downscale: float = checked(1.0, ge=1.0)  # training resolution; 1.0 and width None: stage 1's resolution
    width: int | None = checked(None, ge=1)
    batch_views: int = checked(1, ge=1)
    # memory (MiB) for the frozen geometry's recorded renders (Backbone.colour_operator): a view recorded once is
    # rendered as a sparse product of its colours from then on; views past the budget render as usual; 0: never
    frozen_mb: int = checked(2048, ge=0)
    log_every: int = checked(100, ge=1)
    checkpoint_every: int = checked(5000, ge=0)
    resume: str = checked("auto", choices=("auto", "never", "must"))
    progress: bool = True
    cache_dir: str | None = None  # pseudo-colour/guidance cache; default <arcsem cache root>/colorize
    losses: dict[str, Any] = field(default_factory=lambda: {k: dict(v) for k, v in DEFAULT_LOSSES.items()})
    optim: OptimConfig = field(default_factory=OptimConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    # pseudo-colours take each view's SEM brightness (arcsem.colorize.shading): auto (a line fitted to the
    # references' colour against their grey; flat where the colours do not follow it) | off (copied as they are)
    shading: str = checked("auto", choices=("auto", "off"))
    # the background outside the specimen masks: auto (the references' background colour as a line of the grey,
    # the pseudo-colour target of every other view's background, arcsem.colorize.background) | off (no target there)
    background: str = checked("auto", choices=("auto", "off"))
    # specimen pixels no pseudo-colour or surface spread reaches: grey (the references' expected colour at the
    # pixel's grey level, arcsem.colorize.prior) | off (no target there: they keep the stage-1 grey)
    prior: str = checked("grey", choices=("grey", "off"))
    # auto: each reference held out in turn chooses the surface spread, the shading, the prior and whether TCM/CCM act
    # (one reference: its two halves choose the surface spread and the prior; arcsem.colorize.validate; recorded in
    # metrics.json) | off (the settings as written)
    validate: str = checked("auto", choices=("auto", "off"))
    guard: GuardConfig = field(default_factory=GuardConfig)


@dataclass
class ReaderOptions:
    """Options every reader shares (conf/dataset/*.yaml)."""

    downscale: float = checked(1.0, ge=1.0)  # images and cameras are shrunk by this factor (cv2 INTER_AREA)
    split: str = checked("auto", choices=SPLIT_MODES)  # auto: the dataset's own split (frame `split` keys /
    # separate files), else all train
    test_every: int = checked(8, ge=2)  # split=every_k: views 0, k, 2k, ... (in file order) are test views
    max_views: int | None = checked(None, ge=2)  # keep at most this many views, evenly spaced, before splitting
    holdout: list[str] = field(default_factory=list)  # split=holdout: the test views, by name (a leave-one-out
    # sweep: dataset.split=holdout dataset.holdout=[v_02],[v_03],[v_04])
    # true: colour views are read as their luminance (Rec. 709, as an SEM would see them), their colour kept as the
    # view's ground-truth colour (stage 2's colour metrics): any colour multi-view dataset becomes a colourisation
    # benchmark, references by file (colorize.references=[.../r_0.png])
    grey: bool = False


MESH_FORMATS = ("ply", "glb", "obj")
RENDER_LAYERS = ("gray", "color", "depth", "normal")


@dataclass
class MeshConfig:
    """``mesh``: TSDF mesh export (:mod:`arcsem.mesh`; defaults as used for the figures in docs/mesh.md)."""

    enabled: bool = True  # export at the end of stage 1 (grey) and stage 2 (coloured)
    voxel_size: float | None = None  # scene units; None: voxel_factor x the training pixel footprint
    voxel_factor: float = 1.0
    trunc: float = 6.0  # truncation distance in voxels (docs/mesh.md: 4 -> 1.11 %, 6 -> 0.90 % Chamfer)
    max_voxels: int = 1 << 24  # 16.8 M voxels, ~340 MB while fusing
    # views per orbit elevation fused besides the training views; 0 (training views only) measured best on
    # the built-in scene: orbit views show the model from where no image constrained it (docs/mesh.md)
    orbit_frames: int = 0
    orbit_elevations: list[float] = field(default_factory=lambda: [20.0, 50.0])
    # orbits only over the azimuths and elevations the training cameras span (what the model saw);
    # false: full turns (views of sides no training view saw add the model's guesses to the mesh)
    orbit_in_range: bool = True
    alpha_min: float = 0.5  # rendered alpha that counts as surface (views without masks)
    use_masks: bool = True  # the dataset's specimen masks decide foreground on training views
    carve: bool = True  # background pixels clear the space in front of them
    min_component: float = 0.05  # drop components with fewer faces than this x the largest's
    formats: list[str] = field(default_factory=lambda: ["ply", "glb"])
    chamfer_points: int = 1_000_000  # mesh samples for the Chamfer distance (built-in scene; see groundtruth.py)
    impl: str = "auto"  # TSDF fusion: auto (the fused C++ kernel where it builds) | torch (the reference) | cpp

    def check(self) -> None:
        """ConfigError for a rule the field types cannot say: known formats, a positive voxel, >= 1-voxel trunc."""
        bad = set(self.formats) - set(MESH_FORMATS)
        if bad:
            raise ConfigError(f"mesh.formats: unknown format(s) {sorted(bad)}; valid: {', '.join(MESH_FORMATS)}")
        if self.voxel_size is not None and not self.voxel_size > 0:
            raise ConfigError(f"mesh.voxel_size must be > 0 (scene units) or null, got {self.voxel_size}")
        if not self.trunc >= 1:
            raise ConfigError(f"mesh.trunc must be >= 1 voxel, got {self.trunc}")
        if self.impl not in ("auto", "torch", "cpp"):
            raise ConfigError(f"mesh.impl: '{self.impl}' is not one of auto, torch, cpp")


@dataclass
class RenderConfig:
    """``render`` (``stage=render``, :mod:`arcsem.export.render`): which run, which orbit, which videos."""

    run: str | None = None  # the finished run folder to render (required for stage=render)
    frames: int = 200  # 10 s at 20 fps
    fps: int = 20
    azimuth: list[float] = field(default_factory=lambda: [0.0, 360.0])  # start, end (degrees)
    elevation: float = 20.0  # degrees above the orbit plane
    width: int | None = None  # None: the training width
    height: int | None = None  # None: the training aspect ratio
    camera: str | None = None  # pinhole | orthographic; None: the training cameras' model
    zoom: float = 1.0
    layers: list[str] = field(default_factory=lambda: list(RENDER_LAYERS))
    alpha_min: float = 0.5  # rendered alpha that counts as surface in the depth/normal videos

    def orbit(self):
        """The :class:`arcsem.orbit.OrbitConfig` of these settings."""
        from .orbit import OrbitConfig

        return OrbitConfig(frames=self.frames, azimuth=tuple(self.azimuth), elevation=self.elevation,
                           width=self.width, height=self.height, camera=self.camera, zoom=self.zoom)

    def check(self) -> None:
        """ConfigError for unknown or no layers, an fps outside 1..120 or an orbit :mod:`arcsem.orbit` refuses."""
        bad = [x for x in self.layers if x not in RENDER_LAYERS]
        if bad or not self.layers:
            raise ConfigError(f"render.layers: unknown or no layer(s) {bad}; valid: {', '.join(RENDER_LAYERS)}")
        if not 1 <= self.fps <= 120:
            raise ConfigError(f"render.fps must be in 1..120, got {self.fps}")
        self.orbit().validate()
