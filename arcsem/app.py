"""The work of one ``arcsem`` run, as a plain function tests can call after ``compose(...)``.

``run(cfg)`` validates the config once (:class:`~arcsem.runconfig.RunConfig`, checked by the stage's checks:
:mod:`arcsem.stages`), seeds, loads the scene, runs the stage ``cfg.stage`` names and writes into the run directory:

* ``config.yaml``: the resolved config;
* ``metrics.json``: seed, git revision, overrides, backbone, timings and whatever the stage returns
  (atomic writes: :mod:`arcsem.files`).

Stages (the registry :data:`arcsem.stages.STAGES`): ``gray`` (:func:`arcsem.train.run_stage1`), ``color``
(:func:`arcsem.colorize.run_stage2`), ``all`` (both), ``check`` (load the scene and build the backbone, nothing
trained: validates a dataset/plugin/config combination in seconds and prints a summary), ``render`` (orbit videos
of the finished run ``render.run``: :mod:`arcsem.export.render`).
"""
from __future__ import annotations

import logging
import os
import random
import subprocess
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from .errors import Interrupted
from .files import write_json_atomic, write_text_atomic

log = logging.getLogger(__name__)

__all__ = [
    "git_revision",
    "run",
    "run_directory",
    "seed_everything",
]

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
    else:
        from .preflight import check_threads

        check_threads(threads)
    import torch

    torch.set_num_threads(threads)
    return threads


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


def _run_stages(rc: Any, scene: Any, run_dir: Path, stages: tuple[str, ...], metrics: dict,
                t_start: float) -> None:
    """Run ``stages`` in order; ``metrics.json`` is written after each, and records a failure before re-raising."""
    from .stages import STAGES, resolve

    for name in stages:
        t0 = time.perf_counter()
        try:
            result = resolve(STAGES.get(name).run, name)(rc, scene, run_dir) or {}
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
    ``metrics.json`` and checked. The whole config is validated first, once (:func:`arcsem.stages.check_config`),
    the run folder is locked, and while the stages run no file outside the run folder and the cache is written
    (:mod:`arcsem.guard`).
    """
    from .data import load_scene
    from .guard import allowed_roots, protect
    from .locks import run_folder_lock
    from .runconfig import RunConfig
    from .share import cache_root
    from .stages import STAGES, check_config, check_scene, resolve

    t_start = time.perf_counter()
    stage = str(cfg.stage)
    if overrides is None:
        _, overrides = _hydra_info()
    rc = RunConfig(cfg)  # every group validated once, when first read (by the stage's checks)
    check_config(rc, stage, overrides)
    entry = STAGES.get(stage)
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
        if not entry.needs_scene:  # e.g. stage=render: reads a finished run (its own dataset and models)
            folders = list(resolve(entry.input_dirs, stage)(rc)) if entry.input_dirs else []
        else:
            t0 = time.perf_counter()
            scene = load_scene(rc.dataset)
            metrics["timings"]["load_scene_s"] = time.perf_counter() - t0
            metrics["dataset"].update(root=scene.root, **_scene_summary(scene))
            for warning in check_scene(rc, scene, stage, run_dir):
                log.warning(warning)
                metrics["warnings"].append(warning)
            files, folders = _inputs(scene)
        with protect(allowed_roots(run_dir, cache_root(cfg)), inputs=files, input_dirs=folders,
                     own=[run_dir, cache_root(cfg)]):
            _run_stages(rc, scene, run_dir, entry.runs(), metrics, t_start)
        metrics["warnings"] += [w for r in metrics["stages"].values() for part in r.values()
                                if isinstance(part, dict) for w in part.get("warnings") or []]
        metrics["status"] = "complete"
        _write_metrics(run_dir, metrics, t_start)
        page = None
        if cfg.get("report", False):  # the demo: tables, grids and the HTML page of this run
            from .report import build_report

            page = build_report([run_dir], out=run_dir / "report")
            print(f"report: {page}")
        if entry.summary:
            from .run_summary import summary_lines

            print("\n".join(summary_lines(metrics, run_dir, page)), flush=True)
    return metrics
