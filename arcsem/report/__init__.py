"""Reports from run folders: collect ``metrics.json`` files, write tables, image grids and one HTML page.

``build_report(paths, out)`` is what ``arcsem-report`` runs; the pieces live in ``collect``,
``tables``, ``grids``, ``curves`` (training curves) and ``html``.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["build_report", "representative_runs"]


def representative_runs(coll, study: str) -> dict[str, Path]:
    """Row label -> the first finished run of that row (lowest seed), in the study's row order."""
    from .collect import STUDIES

    df = coll.runs
    if not len(df):
        return {}
    df = df[df["study"] == study].sort_values(["seed", "run_dir"], na_position="last")
    spec = STUDIES[study]
    order = [r for r in spec.rows if r in set(df["row"])] + sorted(set(df["row"].dropna()) - set(spec.rows))
    return {spec.rows.get(r, r): Path(df[df["row"] == r]["run_dir"].iloc[0]) for r in order}


def build_report(paths: list[str | Path], out: str | Path | None = None) -> Path:
    """Collect every run under ``paths`` and write the report into ``out`` (default ``paths[0]/report``).

    Returns the path of ``index.html``.
    """
    from ..errors import DataError
    from .collect import collect
    from .curves import training_curves
    from .formats import write_tables
    from .grids import study_grids
    from .groundtruth import GroundTruth
    from .html import copy_videos, files_table, write_page

    paths = [Path(p) for p in paths]
    for p in paths:
        if not p.is_dir():
            raise DataError(f"{p}: no such run or multirun folder")
    out = Path(out) if out is not None else paths[0] / "report"
    out.mkdir(parents=True, exist_ok=True)
    for sub in ("grids", "curves"):  # this report's images replace an earlier report's (ground-truth tiles kept)
        for stale in (out / sub).glob("*.png"):
            stale.unlink()
    coll = collect(paths, exclude=out)
    tables = write_tables(coll, out)
    grids, videos, curves, files = {}, {}, {}, {}
    gt = GroundTruth(out / "grids" / "gt")
    for study in tables:
        runs = representative_runs(coll, study)
        grids[study] = study_grids(study, runs, out / "grids", gt)
        videos[study] = copy_videos(study, runs, out)
        curves[study] = training_curves(runs, out / "curves" / f"{study}.png")
        files[study] = files_table(runs, out)
    return write_page(out, tables, grids, videos, [str(p) for p in paths], len(coll.runs), curves, files)
