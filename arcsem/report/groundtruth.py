"""Ground-truth tiles for the grids when a run folder holds none: read the run's dataset again.

The dataset config is taken from the run's ``config.yaml`` and loaded with
:func:`arcsem.data.load_scene` (once per distinct config per report). A dataset that cannot be
loaded (moved, not readable) gives no tile, and the grid shows "missing" instead.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

__all__ = ["GroundTruth"]


class GroundTruth:
    """Writes ``<kind>_<view>.png`` tiles (kind: gray | depth | color) into ``folder`` on demand."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self._scenes: dict[str, object] = {}

    def _scene(self, run: Path):
        try:
            cfg = yaml.safe_load((Path(run) / "config.yaml").read_text()) or {}
        except (FileNotFoundError, yaml.YAMLError):
            return None
        ds = cfg.get("dataset")
        if not isinstance(ds, dict) or "kind" not in ds:
            return None
        key = json.dumps(ds, sort_keys=True, default=str)
        if key not in self._scenes:
            from ..data import load_scene
            from ..errors import ArcsemError

            try:
                self._scenes[key] = load_scene(ds)
            except (ArcsemError, OSError, ValueError, KeyError):
                self._scenes[key] = None
        return self._scenes[key]

    def tile(self, run: Path, name: str, kind: str) -> Path | None:
        """Path of the ground-truth tile of view ``name``, or None if the dataset lacks it."""
        path = self.folder / f"{kind}_{name}.png"
        if path.is_file():
            return path
        scene = self._scene(run)
        img = None if scene is None else _image(scene, name, kind)
        if img is None:
            return None
        import cv2

        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), img[..., ::-1])
        return path


def _image(scene, name: str, kind: str) -> np.ndarray | None:
    """``[H, W, 3]`` uint8 RGB ground truth of view ``name`` from whichever split holds it."""
    for split in (scene.test, scene.train):
        if name not in split.names:
            continue
        i = split.index(name)
        if kind == "depth":
            if split.depths is None:
                return None
            from ..visual import DEPTH_SPAN, depth_display  # the evaluation renders' colouring: tiles compare

            gt = split.depths[i]
            mask = split.masks[i] if split.masks is not None else None
            return depth_display(gt, gt, mask, gt > 0, DEPTH_SPAN * scene.scale[0])[1]
        src = split.colors if kind == "color" else (split.clean if split.clean is not None else split.images)
        if src is None:
            return None
        return (src[i].detach().cpu().clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8)
    return None
