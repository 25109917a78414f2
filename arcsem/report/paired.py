"""Paired-by-seed differences between two rows of a study (see ``benchmarks/paired_seeds.py``).

Two rows trained with the same seeds start alike (initial points, view order); the mean of the
per-seed differences B - A and its t-interval say whether B differs from A beyond run-to-run noise.
"""
from __future__ import annotations

import difflib
import math

import pandas as pd
from scipy import stats

from ..errors import DataError

__all__ = ["LOWER_IS_BETTER", "describe", "lower_is_better", "pair", "summary"]

LOWER_IS_BETTER = ("mae", "lpips", "error")


def lower_is_better(metric: str) -> bool:
    """Whether a smaller value of ``metric`` (a flattened column name) is better."""
    return any(k in metric for k in LOWER_IS_BETTER)


def pair(df: pd.DataFrame, a: str, b: str, metric: str) -> tuple[pd.DataFrame, list]:
    """``(table, unpaired)``: per seed the metric of rows ``a``, ``b`` and ``delta = b - a``; the seeds
    that have only one of the two rows."""
    if metric not in df.columns:
        near = difflib.get_close_matches(metric, [str(c) for c in df.columns], n=5, cutoff=0.5)
        raise DataError(f"metric {metric!r} is in no run; closest columns: {near}")
    sub = df[df["row"].isin([a, b])]
    seeds = pd.to_numeric(sub["seed"], errors="coerce")  # overrides give "3", metrics.json 3
    if seeds.notna().all():
        sub = sub.assign(seed=seeds.astype(int))
    dup = sub[sub.duplicated(["row", "seed"], keep=False)]
    if len(dup):
        raise DataError("several runs of the same row and seed:\n" + dup[["row", "seed", "run_dir"]]
                        .to_string(index=False))
    wide = sub.pivot(index="seed", columns="row", values=metric)
    for r in (a, b):
        if r not in wide.columns:
            raise DataError(f"no run of row {r!r}; rows found: {sorted(df['row'].dropna().unique())}")
    unpaired = wide.index[wide[[a, b]].isna().any(axis=1)].tolist()
    wide = wide.dropna(subset=[a, b])[[a, b]]
    wide["delta"] = wide[b] - wide[a]
    return wide, unpaired


def summary(delta: pd.Series, lower: bool) -> dict:
    """Mean, std, 95 % t-interval of the mean and B's wins over ``n`` paired seeds (``lower``: a
    smaller value is better, so B wins where ``delta < 0``)."""
    n = len(delta)
    mean = float(delta.mean())
    sd = float(delta.std(ddof=1)) if n > 1 else math.nan
    half = float(stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n)) if n > 1 else math.nan
    wins = int((delta < 0).sum() if lower else (delta > 0).sum())
    return {"n": n, "mean": mean, "std": sd, "ci_low": mean - half, "ci_high": mean + half, "b_wins": wins}


def describe(s: dict, b: str) -> str:
    """One line of a :func:`summary` ``s`` for row ``b``: mean, std, 95 % interval, wins."""
    return (f"mean {s['mean']:+.4f}  std {s['std']:.4f}  95% CI [{s['ci_low']:+.4f}, {s['ci_high']:+.4f}]"
            f"  {b} better at {s['b_wins']}/{s['n']} seeds")
