"""``stage=gray`` (stage 1) as :mod:`arcsem.stages` runs it: its checks and its runner.

The checks read the run's :class:`~arcsem.runconfig.RunConfig` (each group validated once there); the runner trains
in the run folder or, with ``share_stage1: true``, once per stage-1 config in the shared cache (:mod:`arcsem.share`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..preflight import MIN_IMAGE_SIZE, training_size

__all__ = ["check_losses", "check_scene", "check_train_config", "late_reset_warning", "run_gray_stage"]


def check_train_config(rc: Any) -> None:
    """The ``train`` group against :class:`~arcsem.configs.TrainConfig`."""
    rc.train  # noqa: B018 (reading it validates it)


def check_losses(rc: Any) -> None:
    """The stage-1 losses build for this backbone (each loss's ``Config``, and what it needs of the backbone)."""
    from .stage1 import stage1_losses

    stage1_losses(rc, rc.train, act=rc.act.enabled)


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


def check_scene(rc: Any, scene: Any, stage: str, run_dir: Path) -> list[str]:
    """The training resolution (``train.width``/``downscale``) against the images; a late opacity reset. Warnings."""
    cams, tc = scene.train.cameras, rc.train
    warnings = []
    if tc.width and tc.width > cams.width:
        warnings.append(f"train.width={tc.width} is wider than the images ({cams.width} px): training at "
                        f"{cams.width} px (arcsem never upsamples)")
    w, h = training_size(cams, tc.downscale, tc.width)
    if min(w, h) < MIN_IMAGE_SIZE:
        key = "train.width" if tc.width else "train.downscale"
        raise ConfigError(f"{key}: training images would be {w}x{h} px; arcsem needs at least "
                          f"{MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE} (the SSIM window)")
    late = late_reset_warning(rc.cfg)
    return [*warnings, late] if late else warnings


def run_gray_stage(rc: Any, scene: Any, run_dir: Path) -> dict:
    """Stage 1 in this run's folder, or (``share_stage1: true``) once per stage-1 config in the shared cache.

    Sweeps whose jobs differ only in stage 2 (ablations, reference counts) set ``share_stage1`` so the
    first job trains and the others wait on the cache lock and reuse the model (:mod:`arcsem.share`).
    """
    from ..lazy import import_function

    run_stage1 = import_function("arcsem.train:run_stage1", "stage 'gray'")  # the package's name (tests replace it)
    if not rc.cfg.get("share_stage1", False):
        return run_stage1(rc, scene, run_dir)
    from ..share import ensure_stage1, stage1_result

    path, trained = ensure_stage1(rc.cfg, lambda p: run_stage1(rc, scene, p))
    link = run_dir / "stage1"
    if not link.exists():
        link.symlink_to(path.resolve(), target_is_directory=True)
    return {**(stage1_result(path) or {}), "stage1_dir": str(path), "stage1_reused": not trained}
