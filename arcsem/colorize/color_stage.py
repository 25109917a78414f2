"""``stage=color`` (stage 2) as :mod:`arcsem.stages` checks it; it runs :func:`arcsem.colorize.run_stage2`.

Before the data is read: the ``colorize`` group, its losses against the backbone, the TCM/CCM features, the
reference files. Once the scene is read: the masks and depth ``colorize`` asks for, readable references, images
large enough for TCM/CCM and (``stage=color``) a stage-1 model trained on this dataset. With ``stage=check`` the
scene's problems are warnings (a dataset may be meant for stage 1 alone).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError
from ..preflight import training_size

__all__ = ["FEATURE_STRIDE", "check_colorize_config", "check_config", "check_scene", "check_stage2_inputs"]

FEATURE_STRIDE = 8
"""The coarsest block of every TCM/CCM feature extractor (VGG's relu4_x, DAISY's and the learned CNN's), in pixels of
the images after ``colorize.tcm_downscale``: each side needs at least one such cell."""


def check_colorize_config(rc: Any) -> None:
    """The ``colorize`` group against :class:`~arcsem.configs.ColorizeConfig`."""
    rc.colorize  # noqa: B018 (reading it validates it)


def check_config(rc: Any) -> None:
    """The stage-2 losses build for this backbone; TCM/CCM's features can run here; reference paths exist."""
    from .features import check_features
    from .stage2 import colorize_losses

    cc = rc.colorize
    losses = colorize_losses(cc, rc.backbone_class, rc.loss_configs("colorize.losses"))
    if any(n in losses.terms for n in ("tcm", "ccm")):
        rc.features = check_features(cc.features, cc.tcm_space)  # `auto` resolved here, once per run
    refs = cc.references
    from ..data.io import IMAGE_EXTS

    # a path; in a list, an image file (a name without an image suffix may be a view's: known once the data is read)
    paths = [refs] if isinstance(refs, str) else [f for f in refs or [] if Path(str(f)).suffix.lower() in IMAGE_EXTS]
    for f in paths:
        if ("/" in str(f) or "." in str(f)) and not Path(str(f)).expanduser().exists():
            raise DataError(f"colorize.references: file or folder not found: {f}")


def _check_color_size(rc: Any, cc: Any, scene: Any) -> None:
    """TCM and CCM need stage-2 images of at least ``FEATURE_STRIDE x tcm_downscale`` px a side, and one CCM cell
    (``ccm_downscale``) each way: ConfigError with the figures (32x24 images at the paper's tcm_downscale 4 have a
    6-px side there, and VGG's pooling fails)."""
    terms = [n for n in ("tcm", "ccm") if float(((cc.losses or {}).get(n) or {}).get("weight", 0) or 0) != 0]
    if not terms:
        return
    tc = rc.train
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


def check_stage2_inputs(rc: Any, scene: Any) -> None:
    """What stage 2 needs of the loaded scene: the masks and depth ``colorize`` asks for, images large enough for
    TCM/CCM, and readable references (ConfigError or DataError naming the key, file or view)."""
    from .references import load_references

    cc = rc.colorize
    _check_color_inputs(cc, scene)
    load_references(scene, cc.references)
    _check_color_size(rc, cc, scene)


def check_scene(rc: Any, scene: Any, stage: str, run_dir: Path) -> list[str]:
    """:func:`check_stage2_inputs` (warnings with ``stage=check``) and, for ``stage=color``, the stage-1 model."""
    warnings = []
    try:
        check_stage2_inputs(rc, scene)
    except (ConfigError, DataError) as exc:
        if stage != "check":
            raise
        warnings.append(f"stage 2 (stage=color) would stop here: {exc}")
    if stage == "color":
        from .stage2 import check_stage1_model

        check_stage1_model(rc.cfg, rc.colorize, scene, run_dir)
    return warnings
