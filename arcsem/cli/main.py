"""``arcsem``: the Hydra application (``pkg://arcsem.conf``); the work is :func:`arcsem.app.run`.

Examples::

    arcsem experiment=demo
    arcsem dataset=transforms dataset.path=/data/pollen backbone=gs3d stage=check
    arcsem -m backbone=gs2d,gs3d hydra/launcher=joblib

An error the user can fix ends a run with one ``error:`` line (:mod:`arcsem.cli.errors`), not Hydra's
"Error executing job" and a traceback. In a sweep (``-m``) a failed job prints its line (``error: job 3
(backbone=gs3d seed=1): ...``), leaves a note in ``<sweep dir>/.failed/``, and the other jobs go on; at
the end :class:`SweepSummary` (a Hydra callback, conf/config.yaml) prints how many failed and the
command exits with code 2.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from ..cores import shorter_openmp_spin

shorter_openmp_spin()  # before anything imports torch: OpenMP threads that spin less on a shared machine

import hydra
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from ..schemas import setup
from .errors import EXIT_USER_ERROR, debug_requested, describe, exit_code, with_error_handling

__all__ = ["SweepSummary", "hydra_main", "loss_overrides", "main"]

setup()  # config schemas and plugin config folders, before Hydra composes anything

FAILED_DIR = ".failed"
_failed_sweeps: list[int] = []  # failures counted by SweepSummary in this process


def _sweep_job() -> tuple[Path, int, str] | None:
    """``(sweep folder, job number, "job N (overrides): ")`` in a sweep (``-m``), else None."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized() or HydraConfig.get().mode != RunMode.MULTIRUN:
        return None
    hc = HydraConfig.get()
    return Path(hc.sweep.dir), int(hc.job.num), f"job {hc.job.num} ({' '.join(hc.overrides.task)}): "


@hydra.main(config_path="pkg://arcsem.conf", config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> float | None:
    from ..app import run

    try:
        metrics = run(cfg)
    except BaseException as exc:
        code = exit_code(exc)
        if code is None or debug_requested() or bool(cfg.get("debug", False)):
            raise
        job = _sweep_job()
        label = job[2] if job else ""
        print(f"error: {label}{describe(exc)}", file=sys.stderr, flush=True)
        if job is None or code != EXIT_USER_ERROR:  # Ctrl-C stops the whole sweep
            sys.exit(code)
        note = job[0] / FAILED_DIR / f"job{job[1]}.txt"
        note.parent.mkdir(parents=True, exist_ok=True)
        note.write_text(f"{label}{describe(exc)}\n")
        return None
    value = metrics.get("psnr") if isinstance(metrics, dict) else None  # sweepers may optimise it
    return float(value) if isinstance(value, (int, float)) else None


class SweepSummary(Callback):
    """At the end of a sweep: print how many jobs failed (their notes in ``<sweep dir>/.failed/``)."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        notes = sorted((Path(config.hydra.sweep.dir) / FAILED_DIR).glob("*"))
        if notes:
            _failed_sweeps.append(len(notes))
            print(f"sweep: {len(notes)} job(s) failed (notes in {Path(config.hydra.sweep.dir) / FAILED_DIR})",
                  file=sys.stderr, flush=True)


LOSS_KEYS = ("train.losses.", "colorize.losses.")


def loss_overrides(args: list[str]) -> list[str]:
    """``train.losses.<loss>.<key>=v`` (and ``colorize.losses.``) as ``++train.losses.<loss>.<key>=v``.

    A loss's keys are its ``Config``'s (validated when the loss is built: a mistyped key is named there); the
    presets' YAML lists only the ones they change, so Hydra's struct mode would ask for ``+`` (or ``++`` where a
    preset sets the key) for a documented key such as ``train.losses.dssim.impl``. Other arguments are unchanged.
    """
    out = []
    for a in args:
        key = a.split("=", 1)[0]
        if "=" in a and key.startswith(LOSS_KEYS) and key.count(".") >= 3:
            a = "++" + a
        out.append(a)
    return out


def _main() -> Any:
    sys.argv[1:] = loss_overrides(sys.argv[1:])
    result = hydra_main()
    if _failed_sweeps:
        sys.exit(EXIT_USER_ERROR)
    return result


main = with_error_handling(_main)


if __name__ == "__main__":
    main()
