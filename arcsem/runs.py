"""Open a finished run folder again: its config, its dataset, its grey or coloured model.

The one module that loads what runs left (stage 2, ``arcsem-export``, ``stage=render`` and ``arcsem-view`` use
it): :func:`load_stage1` rebuilds a stage-1 model from its checkpoint, :func:`saved_config` reads the config a
checkpoint was trained with, :func:`find_checkpoint` / :func:`has_colour` find a run's models, :func:`load_run`
opens a run folder.

A run folder (what ``arcsem`` writes) holds ``config.yaml`` (the resolved config), the stage-1
checkpoint ``checkpoints/last.pt`` (or ``stage1/checkpoints/last.pt``, a link to a shared stage-1
model) and, after stage 2, ``colorize/checkpoints/last.pt`` (the coloured model: the same backbone
with its colour parameters trained). Nothing in the folder is written by this module.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import DataError, TrainingError

__all__ = ["RunModel", "find_checkpoint", "has_colour", "load_run", "load_stage1", "read_run_config", "saved_config"]

STAGE1 = ("checkpoints/last.pt", "stage1/checkpoints/last.pt")
STAGE2 = "colorize/checkpoints/last.pt"


@dataclass
class RunModel:
    """A model loaded from a run folder; ``scene`` is at the training resolution."""

    run_dir: Path
    cfg: Any
    scene: Any
    backbone: Any
    colored: bool
    steps: int


def read_run_config(run_dir: Path) -> Any:
    """The run's ``config.yaml`` as a DictConfig (DataError naming the file if absent or unreadable)."""
    from omegaconf import OmegaConf

    path = Path(run_dir) / "config.yaml"
    if not Path(run_dir).is_dir():
        raise DataError(f"{run_dir}: no such run folder")
    if not path.is_file():
        raise DataError(f"{path}: missing; is {run_dir} a folder written by arcsem?")
    try:
        return OmegaConf.load(path)
    except Exception as exc:  # noqa: BLE001  (yaml errors of several kinds)
        raise DataError(f"{path}: not a readable config ({type(exc).__name__})") from None


def has_colour(run_dir: Path) -> bool:
    """True when the run has a stage-2 (coloured) checkpoint."""
    return (Path(run_dir) / STAGE2).is_file()


def find_checkpoint(run_dir: Path, colored: bool = False) -> Path:
    """The stage-1 checkpoint, or with ``colored`` the stage-2 one (DataError listing where it looked)."""
    run_dir = Path(run_dir)
    cands = [run_dir / STAGE2] if colored else [run_dir / p for p in STAGE1]
    for c in cands:
        if c.is_file():
            return c
    what = "coloured (stage-2)" if colored else "stage-1"
    raise DataError(f"{run_dir}: no {what} checkpoint (looked for {', '.join(str(c) for c in cands)})")


def load_run(run_dir: str | Path, colored: bool | None = None, device: str = "cpu") -> RunModel:
    """Load the grey model (``colored=False``), the coloured one (``True``) or the coloured one where
    the run has it (``None``), with the run's dataset at the training resolution."""
    from omegaconf import OmegaConf

    from .data import load_scene
    from .train.checkpoint import load_checkpoint, load_module_state
    from .train.stage1 import prepare_scene, train_config

    run_dir = Path(run_dir)
    cfg = read_run_config(run_dir)
    colored = has_colour(run_dir) if colored is None else colored
    ckpt1 = find_checkpoint(run_dir, colored=False)
    ckpt2 = find_checkpoint(run_dir, colored=True) if colored else None
    scene = load_scene(cfg.dataset)
    backbone, _ = load_stage1(ckpt1, scene, {"device": device})
    state = load_checkpoint(ckpt1)
    scene = prepare_scene(scene, train_config(OmegaConf.create(state.get("config") or {"train": {}})))
    steps = int(state.get("step", 0))
    if ckpt2 is not None:
        s2 = load_checkpoint(ckpt2)
        backbone.act = None  # stage 2 has no ACT (arcsem/colorize/stage2.py)
        load_module_state(backbone, s2["model"])
        steps = int(s2.get("step", 0))
        backbone.eval()
    return RunModel(run_dir, cfg, scene, backbone, bool(colored), steps)


def saved_config(checkpoint: str | Path) -> dict:
    """The config stored in a checkpoint (what it was trained with; ``{}`` when it stores none)."""
    from .train.checkpoint import load_checkpoint

    return load_checkpoint(checkpoint).get("config") or {}


def load_stage1(path: str | Path, scene: Any, cfg: Any = None):
    """Rebuild ``(backbone, act)`` from a stage-1 checkpoint (``run_dir/checkpoints/last.pt``).

    The backbone and ACT are built from the config stored in the checkpoint (``cfg`` is used only for
    ``device`` and for checkpoints without a stored config); ``scene`` provides the training cameras.
    Returns the models in eval mode; ``act`` is None when stage 1 ran without ACT.
    """
    from omegaconf import OmegaConf

    from .runconfig import run_config
    from .train.checkpoint import load_checkpoint, load_module_state
    from .train.stage1 import build_model, prepare_scene, stage1_config

    state = load_checkpoint(path)
    cfg = run_config(cfg).cfg if cfg is not None else None
    saved = state.get("config") or {}
    if not saved.get("backbone") and cfg is None:
        raise TrainingError(f"{path}: checkpoint has no stored config; pass the stage-1 cfg")
    base = OmegaConf.create({**(saved or stage1_config(cfg)), "device": str((cfg or {}).get("device", "cpu"))})
    rc = run_config(base)  # the checkpoint's own config: another input than the run's, validated once here
    backbone, act = build_model(rc, prepare_scene(scene, rc.train))
    load_module_state(backbone, state["model"])
    if act is not None and state.get("act") is not None:
        load_module_state(act, state["act"])
    backbone.eval()
    return backbone, act
