"""The work of one ``arcsem`` run, as a plain function tests can call after ``compose(...)``.

``run(cfg)`` seeds, loads the scene, dispatches on ``cfg.stage`` and writes into the run directory:

* ``config.yaml``: the resolved config;
* ``metrics.json``: seed, git revision, overrides, backbone, timings and whatever the stage returns
  (atomic writes: a temporary file then ``os.replace``).

Stages: ``gray`` (:func:`arcsem.train.run_stage1`), ``color`` (:func:`arcsem.colorize.run_stage2`),
``all`` (both), ``check`` (load the scene and build the backbone, nothing trained: validates a
dataset/plugin/config combination in seconds and prints a summary), ``render`` (orbit videos of the
finished run ``render.run``: :mod:`arcsem.export.render`).
"""
from __future__ import annotations

import json
import os
import random
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from .errors import ConfigError, PluginError

__all__ = [
    "STAGES",
    "git_revision",
    "run",
    "run_directory",
    "seed_everything",
    "write_json_atomic",
    "write_text_atomic",
]

STAGES = ("gray", "color", "all", "check", "render")


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _jsonable(obj: Any) -> Any:
    """Tensors/arrays/numpy scalars -> lists/floats; NaN/inf stay floats (written as NaN/Infinity)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):  # torch / numpy
        return _jsonable(obj.tolist())
    return obj


def write_json_atomic(path: str | Path, obj: Any) -> None:
    """``json.dump`` of ``obj`` (tensors and arrays converted) to ``path``, atomically."""
    write_text_atomic(path, json.dumps(_jsonable(obj), indent=2, sort_keys=False) + "\n")


def git_revision() -> str:
    """``git rev-parse HEAD`` at the package root, or ``"unknown"`` (not a git checkout, no git)."""
    root = Path(__file__).resolve().parent.parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev or "unknown"


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch."""
    import numpy as np
    import torch

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _hydra_info() -> tuple[Path | None, list[str]]:
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None, []
    hc = HydraConfig.get()
    return Path(hc.runtime.output_dir), list(hc.overrides.task)


def run_directory(cfg: DictConfig) -> Path:
    """Hydra's output dir, else ``cfg.run_dir``, else ``outputs/<date>/<time>`` (calls without Hydra)."""
    out, _ = _hydra_info()
    if out is not None:
        return out
    rd = cfg.get("run_dir") if isinstance(cfg, DictConfig) else None
    return Path(rd) if rd else Path("outputs") / time.strftime("%Y-%m-%d/%H-%M-%S")


def set_threads(threads: Any) -> None:
    """``threads``: torch (and fused-kernel) threads of this job; None keeps torch's default (all cores).

    Jobs that share a machine (``hydra/launcher=joblib``, several runs at once) should divide the
    cores between them: oversubscribed threads spin-wait and slow every job down several times.
    """
    if threads is None:
        return
    if not isinstance(threads, int) or threads < 1:
        raise ConfigError(f"threads: expected a positive integer or null, got {threads!r}")
    import torch

    torch.set_num_threads(threads)


def _stage_function(stage: str) -> Callable[..., dict]:
    module, func = {"gray": ("arcsem.train", "run_stage1"), "color": ("arcsem.colorize", "run_stage2"),
                    "render": ("arcsem.export.render", "run_render_stage")}[stage]
    import importlib

    try:
        return getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        raise PluginError(f"stage '{stage}' needs {module}.{func}, which is not available: {exc}") from None


def _gray_stage(cfg: DictConfig, scene: Any, run_dir: Path) -> dict:
    """Stage 1 in this run's folder, or (``share_stage1: true``) once per stage-1 config in the shared cache.

    Sweeps whose jobs differ only in stage 2 (ablations, reference counts) set ``share_stage1`` so the
    first job trains and the others wait on the cache lock and reuse the model (:mod:`arcsem.share`).
    """
    run_stage1 = _stage_function("gray")
    if not cfg.get("share_stage1", False):
        return run_stage1(cfg, scene, run_dir)
    from .share import ensure_stage1, stage1_result

    path, trained = ensure_stage1(cfg, lambda p: run_stage1(cfg, scene, p))
    link = run_dir / "stage1"
    if not link.exists():
        link.symlink_to(path.resolve(), target_is_directory=True)
    return {**(stage1_result(path) or {}), "stage1_dir": str(path), "stage1_reused": not trained}


def _check_stage(cfg: DictConfig, scene: Any, run_dir: Path) -> dict:
    """Build the backbone and ACT as stage 1 would (validates dataset, plugin and their configs); trains nothing."""
    from .check_summary import check_summary
    from .plugins import BACKBONES
    from .train.stage1 import build_model

    model, act = build_model(cfg, scene)
    result = {"backbone_origin": BACKBONES.origin(cfg.backbone.name), "primitives": int(model.num_primitives()),
              "act": act is not None}
    print(check_summary(cfg, scene, result))
    return result


def _scene_summary(scene: Any) -> dict:
    cams = scene.train.cameras
    return {"train_views": len(scene.train), "test_views": len(scene.test), "image_size": [cams.width, cams.height],
            "camera_model": cams.model, "references": sorted(scene.references)}


def run(cfg: DictConfig, run_dir: str | Path | None = None) -> dict:
    """Run ``cfg.stage`` and write ``config.yaml`` and ``metrics.json`` into the run directory."""
    from .data import load_scene

    t_start = time.perf_counter()
    stage = str(cfg.stage)
    if stage not in STAGES:
        raise ConfigError(f"stage: unknown stage '{stage}'; available: {', '.join(STAGES)}")
    run_dir = Path(run_dir) if run_dir is not None else run_directory(cfg)
    _, overrides = _hydra_info()
    write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
    seed_everything(int(cfg.seed))
    set_threads(cfg.get("threads"))
    metrics: dict[str, Any] = {
        "seed": int(cfg.seed), "git_revision": git_revision(), "overrides": overrides, "stage": stage,
        "backbone": str(cfg.backbone.name), "dataset": {"kind": str(cfg.dataset.kind)},
        "timings": {},
    }
    t0 = time.perf_counter()
    scene = load_scene(cfg.dataset) if stage != "render" else None  # render: the run's own dataset
    metrics["timings"]["load_scene_s"] = time.perf_counter() - t0
    if scene is not None:
        metrics["dataset"].update(root=scene.root, **_scene_summary(scene))
    stages = {"gray": ["gray"], "color": ["color"], "all": ["gray", "color"], "check": ["check"],
              "render": ["render"]}[stage]
    metrics["stages"] = {}
    for name in stages:
        func = {"check": _check_stage, "gray": _gray_stage}.get(name) or _stage_function(name)
        t0 = time.perf_counter()
        result = func(cfg, scene, run_dir) or {}
        metrics["timings"][f"{name}_s"] = time.perf_counter() - t0
        metrics["stages"][name] = result
        metrics.update({k: v for k, v in result.items() if k not in ("timings", "stages")})
        metrics["timings"].update({f"{name}.{k}": v for k, v in (result.get("timings") or {}).items()})
    metrics["timings"]["total_s"] = time.perf_counter() - t_start
    write_json_atomic(run_dir / "metrics.json", metrics)
    if cfg.get("report", False):  # the demo: tables, grids and the HTML page of this run
        from .report import build_report

        page = build_report([run_dir], out=run_dir / "report")
        print(f"report: {page}")
    return metrics

