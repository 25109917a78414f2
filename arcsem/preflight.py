"""Everything a run will need, checked before it trains anything.

:func:`check_config` runs before the dataset is read: the top-level keys (``seed``, ``device``,
``threads``) and, for every stage the run will execute, its config group (ranges, types, choices), its
backbone and loss plugins. :func:`check_scene` runs once the scene is loaded: image sizes (the SSIM
window, the training resolution), the colour references, and for ``stage=color`` the stage-1 model,
which must have been trained on this dataset (:func:`arcsem.scene.scene_fingerprint`). So
``stage=all colorize.references=seven`` fails in seconds, not after stage 1.

Every problem raises :class:`~arcsem.errors.ConfigError` or :class:`~arcsem.errors.DataError` naming the
key, file or view; warnings (the training width capped at the images' width) are returned as strings.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .errors import ConfigError, DataError, PluginError

__all__ = ["FEATURE_STRIDE", "MIN_IMAGE_SIZE", "STAGE_PLAN", "check_config", "check_device", "check_flag_overrides",
           "check_scene", "check_stage2_inputs", "training_size"]

STAGE_PLAN = {"gray": ("gray",), "color": ("color",), "all": ("gray", "color"), "check": ("gray", "color"),
              "render": ("render",)}
"""The training stages each ``stage`` value runs or, for ``check``, validates (stage 2's references and model
only where it can: their problems are warnings, since a dataset may be meant for stage 1 alone)."""

MIN_IMAGE_SIZE = 11
"""Smallest image side arcsem trains or scores on: the 11-pixel SSIM window."""


def check_device(device: Any) -> None:
    """``device`` must name a torch device this machine has."""
    import torch

    try:
        dev = torch.device(str(device))
    except RuntimeError:
        raise ConfigError(f"device: '{device}' is not a device; use cpu, cuda or cuda:<index>") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
            raise ConfigError(f"device={device}: no CUDA device is available on this machine (torch is {build}); "
                              "use device=cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device={device}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise ConfigError(f"device: '{device}' is not supported; use cpu or cuda")


def _check_top_level(cfg: Any) -> None:
    seed = cfg.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise ConfigError(f"seed: expected an integer, got {seed!r}")
    threads = cfg.get("threads")
    if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool) or threads < 1):
        raise ConfigError(f"threads: expected a positive integer or null, got {threads!r}")
    check_device(cfg.get("device", "cpu"))


def _check_gray(cfg: Any) -> None:
    from .train.stage1 import act_config, backbone_config, stage1_losses, train_config

    tc = train_config(cfg)
    _check_rasterizer(backbone_config(cfg), cfg)  # the plugin's Config
    stage1_losses(cfg, tc, act=act_config(cfg).enabled)


def _check_rasterizer(bcfg: dict, cfg: Any) -> None:
    """``backbone.rasterizer=gsplat`` (the optional CUDA rasteriser) needs gsplat and ``device=cuda``."""
    if bcfg.get("rasterizer") == "gsplat":
        from .backbones.gaussians.gsplat_bridge import require_gsplat

        require_gsplat(cfg.get("device", "cpu"))


def _check_gsplat_scene(bcfg: dict, scene: Any) -> None:
    """``backbone.rasterizer=gsplat``: the scene's cameras, the 2DGS low-pass filter and tile size must be ones
    gsplat draws."""
    if bcfg.get("rasterizer") != "gsplat":
        return
    from .backbones.gaussians.gsplat_bridge import gsplat_cameras, require_2dgs_tile, require_lowpass

    two_d = bcfg.get("name") == "gs2d"
    for split in (scene.train, scene.test):
        if len(split):
            gsplat_cameras(split.cameras, two_d=two_d)
    if two_d:
        require_lowpass(float(bcfg.get("lowpass_sigma", 2**-0.5)))
        require_2dgs_tile(int(bcfg.get("tile", 16)))


def _check_color(cfg: Any) -> None:
    from .colorize.stage2 import colorize_config, colorize_losses
    from .plugins import BACKBONES

    cc = colorize_config(cfg)
    _check_rasterizer(dict(cfg.backbone), cfg)
    losses = colorize_losses(cc, BACKBONES.get(str(cfg.backbone.name)))
    if any(n in losses.terms for n in ("tcm", "ccm")):
        _check_features(cc)
    refs = cc.references
    files = [refs] if isinstance(refs, str) else list(refs or [])
    for f in files:
        if ("/" in str(f) or "." in str(f)) and not Path(str(f)).expanduser().exists():
            raise DataError(f"colorize.references: file or folder not found: {f}")


def _check_render(cfg: Any) -> None:
    from .export.render import render_config

    rc = render_config(cfg.get("render"))
    if not rc.run:
        raise ConfigError("render.run: set it to the finished run folder to render (stage=render render.run=...)")
    run = Path(rc.run).expanduser()
    if not (run / "config.yaml").is_file():
        raise DataError(f"render.run: {run} is not a finished arcsem run folder (no config.yaml)")


def _check_features(cc: Any) -> None:
    """``colorize.features`` / ``tcm_space``: the extractor can run here and the loss space suits it."""
    from .colorize.features import announce_features

    name = announce_features(cc.features)  # the one line per job that says what `auto` chose
    if name == "daisy":
        import cv2

        if not hasattr(cv2, "xfeatures2d"):
            raise PluginError("colorize.features=daisy needs OpenCV contrib (opencv-contrib-python-headless); "
                              "the installed cv2 has no xfeatures2d")
    if cc.tcm_space == "features" and name not in ("vgg16", "vgg19"):
        raise ConfigError(f"colorize.tcm_space=features: '{name}' features cannot be computed on a colour render; "
                          "use tcm_space=color (or auto)")


def check_flag_overrides(cfg: Any, overrides: list[str]) -> None:
    """A command-line value for a true/false key must read as a boolean.

    The Hydra schemas convert ``train.progress=-7`` to ``True`` (OmegaConf reads any non-zero number as true)
    before a dataclass sees it, so the raw overrides are checked against the composed config's types.
    """
    from omegaconf import OmegaConf

    for item in overrides:
        key, sep, value = item.lstrip("+~").partition("=")
        if not sep or not isinstance(OmegaConf.select(cfg, key, default=None), bool):
            continue
        if value.strip().lower() not in ("true", "false"):
            raise ConfigError(f"{key}: must be true or false, got {value!r}")


def check_config(cfg: Any, stage: str, overrides: list[str] | None = None) -> None:
    """Validate the config of every stage ``stage`` runs (see the module docstring); reads no data.
    ``overrides``: the command line's (Hydra's task overrides), checked by :func:`check_flag_overrides`."""
    from .app import STAGES

    check_flag_overrides(cfg, overrides or [])
    if stage not in STAGES:
        raise ConfigError(f"stage: unknown stage '{stage}'; available: {', '.join(STAGES)}")
    _check_top_level(cfg)
    if stage != "render":
        from .data import check_dataset_config

        check_dataset_config(cfg.dataset)
    for name in STAGE_PLAN[stage]:
        {"gray": _check_gray, "color": _check_color, "render": _check_render}[name](cfg)


def training_size(cams: Any, downscale: float, width: int | None) -> tuple[int, int]:
    """``(w, h)`` of the training images of ``cams`` at ``width`` (never above the images') or ``1 / downscale``."""
    w = min(width, cams.width) if width else round(cams.width / downscale)
    return w, round(cams.height * w / cams.width)


def _check_sizes(cfg: Any, scene: Any, stages: tuple[str, ...]) -> list[str]:
    cams = scene.train.cameras
    if min(cams.width, cams.height) < MIN_IMAGE_SIZE:
        raise DataError(f"{scene.root}: the images are {cams.width}x{cams.height} px ('{scene.train.names[0]}'); "
                        f"arcsem needs at least {MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE} (the SSIM window)")
    if "gray" not in stages:
        return []
    from .train.stage1 import train_config

    tc = train_config(cfg)
    warnings = []
    if tc.width and tc.width > cams.width:
        warnings.append(f"train.width={tc.width} is wider than the images ({cams.width} px): training at "
                        f"{cams.width} px (arcsem never upsamples)")
    w, h = training_size(cams, tc.downscale, tc.width)
    if min(w, h) < MIN_IMAGE_SIZE:
        key = "train.width" if tc.width else "train.downscale"
        raise ConfigError(f"{key}: training images would be {w}x{h} px; arcsem needs at least "
                          f"{MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE} (the SSIM window)")
    return warnings


FEATURE_STRIDE = 8
"""The coarsest block of every TCM/CCM feature extractor (VGG's relu4_x, DAISY's and the learned CNN's), in pixels of
the images after ``colorize.tcm_downscale``: each side needs at least one such cell."""


def _check_color_size(cfg: Any, cc: Any, scene: Any) -> None:
    """TCM and CCM need stage-2 images of at least ``FEATURE_STRIDE x tcm_downscale`` px a side, and one CCM cell
    (``ccm_downscale``) each way: ConfigError with the figures (32x24 images at the paper's tcm_downscale 4 have a
    6-px side there, and VGG's pooling fails)."""
    terms = [n for n in ("tcm", "ccm") if float(((cc.losses or {}).get(n) or {}).get("weight", 0) or 0) != 0]
    if not terms:
        return
    from .train.stage1 import train_config

    tc = train_config(cfg)
    down, width = (cc.downscale, cc.width) if (cc.downscale != 1.0 or cc.width) else (tc.downscale, tc.width)
    w, h = training_size(scene.train.cameras, down, width)
    need = max(FEATURE_STRIDE * cc.tcm_downscale, cc.ccm_downscale)
    if min(w, h) < need:
        off = " ".join(f"colorize.losses.{n}.weight=0" for n in terms)
        verb = "need" if len(terms) > 1 else "needs"
        raise ConfigError(f"colorize: {' and '.join(t.upper() for t in terms)} {verb} stage-2 images of at least "
                          f"{need}x{need} px (tcm_downscale {cc.tcm_downscale} x the features' {FEATURE_STRIDE}-px "
                          f"cells, ccm_downscale {cc.ccm_downscale}); these are {w}x{h} px: lower "
                          f"colorize.tcm_downscale/ccm_downscale or turn them off ({off})")


def _check_color_inputs(cc: Any, scene: Any) -> None:
    """What ``colorize.masks`` and ``colorize.depth`` need from the dataset or the disk."""
    if cc.masks == "dataset" and scene.train.masks is None:
        raise DataError("colorize.masks=dataset but the dataset has no masks; use auto, otsu, grabcut or files")
    if cc.masks == "files" and not (cc.mask_folder and Path(cc.mask_folder).expanduser().is_dir()):
        raise DataError(f"colorize.masks=files needs colorize.mask_folder, an existing folder (got {cc.mask_folder!r})")
    if cc.masks == "sam" and not (cc.sam_checkpoint and Path(cc.sam_checkpoint).expanduser().is_file()):
        raise DataError(f"colorize.masks=sam needs colorize.sam_checkpoint, a Segment Anything checkpoint file "
                        f"(got {cc.sam_checkpoint!r})")
    if cc.depth == "dataset" and scene.train.depths is None:
        raise DataError("colorize.depth=dataset but the dataset has no depth maps; use depth=model")


def late_reset_warning(cfg: Any) -> str | None:
    """A warning when a Gaussian schedule resets the opacities (to 0.01) in the last tenth of stage 1: the run ends
    before they grow back (``train.steps=300`` with the 1500-step schedule reset on its last step: 10 dB)."""
    b, steps = cfg.get("backbone") or {}, int((cfg.get("train") or {}).get("steps") or 0)
    every, until = b.get("opacity_reset_every"), b.get("densify_until")
    if not (b.get("densify", True) and isinstance(every, int) and every > 0 and isinstance(until, int) and steps):
        return None
    last = min(until - 1, steps) // every * every  # resets at iterations k * every < densify_until, <= steps
    if last < every or steps - last >= 0.1 * steps:
        return None
    return (f"backbone.opacity_reset_every={every}: the last opacity reset is at step {last} of {steps}, and the run "
            f"ends before the opacities recover (held-out renders nearly empty); make it fall before step "
            f"{int(0.9 * steps)} (backbone.opacity_reset_every, backbone.densify_until or train.steps)")


def check_stage2_inputs(cfg: Any, cc: Any, scene: Any) -> None:
    """What stage 2 needs of the loaded scene: the masks and depth ``colorize`` asks for, images large enough for
    TCM/CCM, and readable references (ConfigError or DataError naming the key, file or view)."""
    from .colorize.references import load_references

    _check_color_inputs(cc, scene)
    load_references(scene, cc.references)
    _check_color_size(cfg, cc, scene)


def check_scene(cfg: Any, scene: Any, stage: str, run_dir: Path) -> list[str]:
    """Checks that need the loaded scene; returns warnings. ``stage=color`` also checks the stage-1 model."""
    stages = STAGE_PLAN[stage]
    if len(scene.train) < 2:
        raise DataError(f"{scene.root}: {len(scene.train)} training view(s); a 3-D scene needs at least 2 "
                        "(check dataset.split and dataset.max_views)")
    warnings = [*getattr(scene, "warnings", []), *_check_sizes(cfg, scene, stages)]
    if "gray" in stages and late_reset_warning(cfg):
        warnings.append(late_reset_warning(cfg))
    _check_gsplat_scene(dict(cfg.backbone), scene)
    if "color" in stages:
        from .colorize.stage2 import check_stage1_model, colorize_config

        cc = colorize_config(cfg)
        try:
            check_stage2_inputs(cfg, cc, scene)
        except (ConfigError, DataError) as exc:
            if stage != "check":
                raise
            warnings.append(f"stage 2 (stage=color) would stop here: {exc}")
        if stage == "color":
            check_stage1_model(cfg, cc, scene, run_dir)
    return warnings
