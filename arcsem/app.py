"""The work of one ``arcsem`` run, as a plain function tests can call after ``compose(...)``.

``run(cfg)`` seeds, loads the scene, dispatches on ``cfg.stage`` and writes into the run directory:

* ``config.yaml``: the resolved config;
* ``metrics.json``: seed, git revision, overrides, backbone, timings and whatever the stage returns
  (atomic writes: :mod:`arcsem.files`).

Stages: ``gray`` (:func:`arcsem.train.run_stage1`), ``color`` (:func:`arcsem.colorize.run_stage2`),
``all`` (both), ``check`` (load the scene and build the backbone, nothing trained: validates a
dataset/plugin/config combination in seconds and prints a summary), ``render`` (orbit videos of the
finished run ``render.run``: :mod:`arcsem.export.render`).
"""
from __future__ import annotations

import logging
import os
import random
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from .errors import ConfigError, Interrupted, PluginError
from .files import write_json_atomic, write_text_atomic

log = logging.getLogger(__name__)

__all__ = [
    "STAGES",
    "git_revision",
    "run",
    "run_directory",
    "seed_everything",
]

STAGES = ("gray", "color", "all", "check", "render")


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


def set_threads(threads: Any) -> int:
    """``threads``: torch (and fused-kernel) threads of this job; None: the cores this process may use (its CPU
    affinity and cgroup quota, :func:`arcsem.cores.usable_cores`; torch's own default counts the machine's).
    Returns the count set.

    Jobs that share a machine (``hydra/launcher=joblib``, several runs at once) should divide the
    cores between them: oversubscribed threads spin-wait and slow every job down several times.
    """
    if threads is None:
        from .cores import usable_cores

        threads = usable_cores()
    elif not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
        raise ConfigError(f"threads: expected a positive integer or null, got {threads!r}")
    import torch

    torch.set_num_threads(threads)
    return threads


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
            "camera_model": cams.model, "references": sorted(scene.references),
            **({"intensity": scene.intensity} if scene.intensity else {})}


def _inputs(scene: Any) -> tuple[list[str], list[str]]:
    """The scene's input files and the folders they lie in (for :func:`arcsem.guard.protect`)."""
    files = [f for split in (scene.train, scene.test) for f in (split.files or [])]
    return files, sorted({scene.root, *(os.path.dirname(f) for f in files)})


def _write_metrics(run_dir: Path, metrics: dict, t_start: float) -> None:
    """The one writer of ``metrics.json``: strict JSON, a NaN or infinity as ``null`` with its reason in ``nulls``
    (:mod:`arcsem.metrics_json`)."""
    from .metrics_json import strict_metrics

    metrics["timings"]["total_s"] = time.perf_counter() - t_start
    write_json_atomic(run_dir / "metrics.json", strict_metrics(metrics), allow_nan=False)


def _run_stages(cfg: DictConfig, scene: Any, run_dir: Path, stages: tuple[str, ...], metrics: dict,
                t_start: float) -> None:
    """Run ``stages`` in order; ``metrics.json`` is written after each, and records a failure before re-raising."""
    for name in stages:
        func = {"check": _check_stage, "gray": _gray_stage}.get(name) or _stage_function(name)
        t0 = time.perf_counter()
        try:
            result = func(cfg, scene, run_dir) or {}
        except BaseException as exc:
            from .errors import one_line

            metrics["status"] = "interrupted" if isinstance(exc, (KeyboardInterrupt, Interrupted)) else "failed"
            metrics["failed_stage"], metrics["error"] = name, one_line(exc)
            _write_metrics(run_dir, metrics, t_start)
            raise
        metrics["timings"][f"{name}_s"] = time.perf_counter() - t0
        metrics["stages"][name] = result
        metrics.update({k: v for k, v in result.items() if k not in ("timings", "stages")})
        metrics["timings"].update({f"{name}.{k}": v for k, v in (result.get("timings") or {}).items()})
        metrics["completed_stages"].append(name)
        _write_metrics(run_dir, metrics, t_start)


def run(cfg: DictConfig, run_dir: str | Path | None = None, overrides: list[str] | None = None) -> dict:
    """Run ``cfg.stage`` and write ``config.yaml`` and ``metrics.json`` (after every stage) into the run directory.

    ``overrides``: the command line (default: Hydra's task overrides, where Hydra runs the job); recorded in
    ``metrics.json`` and checked. The whole config is validated first (:func:`arcsem.preflight.check_config`),
    the run folder is locked, and while the stages run no file outside the run folder and the cache is written
    (:mod:`arcsem.guard`).
    """
    from .data import load_scene
    from .guard import allowed_roots, protect
    from .locks import run_folder_lock
    from .preflight import STAGE_PLAN, check_config, check_scene
    from .share import cache_root

    t_start = time.perf_counter()
    stage = str(cfg.stage)
    if overrides is None:
        _, overrides = _hydra_info()
    check_config(cfg, stage, overrides)
    run_dir = Path(run_dir) if run_dir is not None else run_directory(cfg)
    with run_folder_lock(run_dir):
        write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
        seed_everything(int(cfg.seed))
        set_threads(cfg.get("threads"))
        metrics: dict[str, Any] = {
            "seed": int(cfg.seed), "git_revision": git_revision(), "overrides": overrides, "stage": stage,
            "backbone": str(cfg.backbone.name), "dataset": {"kind": str(cfg.dataset.kind)}, "status": "running",
            "completed_stages": [], "warnings": [], "timings": {}, "stages": {},
        }
        scene, files, folders = None, [], []
        if stage == "render":  # renders a finished run (its own dataset and models): that run is an input
            folders = [str(Path(str(cfg.render.run)).expanduser().resolve())]
        else:
            t0 = time.perf_counter()
            scene = load_scene(cfg.dataset)
            metrics["timings"]["load_scene_s"] = time.perf_counter() - t0
            metrics["dataset"].update(root=scene.root, **_scene_summary(scene))
            for warning in check_scene(cfg, scene, stage, run_dir):
                log.warning(warning)
                metrics["warnings"].append(warning)
            files, folders = _inputs(scene)
        stages = {"check": ("check",), "render": ("render",)}.get(stage) or STAGE_PLAN[stage]
        with protect(allowed_roots(run_dir, cache_root(cfg)), inputs=files, input_dirs=folders,
                     own=[run_dir, cache_root(cfg)]):
            _run_stages(cfg, scene, run_dir, stages, metrics, t_start)
        metrics["warnings"] += [w for r in metrics["stages"].values() for part in r.values()
                                if isinstance(part, dict) for w in part.get("warnings") or []]
        metrics["status"] = "complete"
        _write_metrics(run_dir, metrics, t_start)
        page = None
        if cfg.get("report", False):  # the demo: tables, grids and the HTML page of this run
            from .report import build_report

            page = build_report([run_dir], out=run_dir / "report")
            print(f"report: {page}")
        if stage in ("gray", "color", "all"):
            from .run_summary import summary_lines

            print("\n".join(summary_lines(metrics, run_dir, page)), flush=True)
    return metrics
