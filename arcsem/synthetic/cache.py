"""The default location of the built-in scene: a cache folder keyed by the scene's parameters."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import asdict
from pathlib import Path

from .write import GENERATOR_VERSION, SceneParams, generate_scene, params_record

__all__ = ["cache_root", "ensure_scene", "scene_key"]

MARKER = ".complete"


def cache_root() -> Path:
    """``${ARCSEM_CACHE:-~/.cache/arcsem}/scenes``."""
    return Path(os.environ.get("ARCSEM_CACHE", Path.home() / ".cache" / "arcsem")).expanduser() / "scenes"


def scene_key(p: SceneParams) -> str:
    """16 hex digits of the SHA-1 of the parameters and the generator version."""
    blob = json.dumps({**params_record(p), "generator_version": GENERATOR_VERSION}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def ensure_scene(path=None, *, progress: bool | None = None, **params) -> Path:
    """``transforms.json`` of the scene ``SceneParams(**params)``, generating it only if needed.

    ``path``: the scene folder (default ``cache_root() / scene_key``). A folder counts as complete
    once its ``.complete`` marker exists; the scene is rendered into a temporary sibling folder
    that is renamed into place at the end, so an interrupted run never leaves a half scene.
    """
    p = SceneParams(**params)
    folder = Path(path) if path is not None else cache_root() / scene_key(p)
    if (folder / MARKER).is_file():
        return folder / "transforms.json"
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = folder.parent / f".{folder.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        generate_scene(tmp, progress=progress, **asdict(p))
        (tmp / MARKER).write_text(json.dumps({**params_record(p), "generator_version": GENERATOR_VERSION}))
        if folder.exists() and not (folder / MARKER).is_file():
            shutil.rmtree(folder)  # a stale incomplete folder (not written by this function)
        try:
            os.replace(tmp, folder)
        except OSError:
            if not (folder / MARKER).is_file():  # lost a race to another process: use its scene
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder / "transforms.json"
