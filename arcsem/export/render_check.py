"""``stage=render``'s check, before anything is read: ``render.run`` names a finished run folder.

The stage itself: :func:`arcsem.export.render.run_render_stage`; its entry: :mod:`arcsem.stages`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError

__all__ = ["check_config", "input_dirs"]


def check_config(rc: Any) -> None:
    """The ``render`` block against :class:`~arcsem.configs.RenderConfig`; ``render.run`` set, with a config.yaml."""
    if not rc.render.run:
        raise ConfigError("render.run: set it to the finished run folder to render (stage=render render.run=...)")
    run = Path(rc.render.run).expanduser()
    if not (run / "config.yaml").is_file():
        raise DataError(f"render.run: {run} is not a finished arcsem run folder (no config.yaml)")


def input_dirs(rc: Any) -> list[str]:
    """The finished run ``render.run`` (its own dataset and models): read, never written, while the stage runs."""
    return [str(Path(str(rc.render.run)).expanduser().resolve())]
