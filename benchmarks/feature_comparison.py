"""Table: held-out colour PSNR inside / outside the pseudo-colour coverage per TCM/CCM feature extractor and
number of references, from the runs' metrics.json (e.g. sweeps of ``experiment=feature_comparison``).

Rows: the recorded extractor (``features``: ``vgg16-random``, ``daisy``, ``learned``, ...) and the
dataset; columns: references (1, 3, 5) x {PSNR in cov., PSNR out cov.} (pooled over held-out views,
:mod:`arcsem.colorize.coverage`), mean ± std over seeds; the held-out coverage is printed below.
With ``--paired A`` each extractor is compared with extractor A per seed (mean difference, 95 %
t-interval; over the whole image, inside and outside the coverage) where two or more seeds pair up.

Usage::

    .venv/bin/python benchmarks/feature_comparison.py SWEEP_OR_RUN [...] [--out table.md] [--paired daisy]
"""
from __future__ import annotations

import argparse
import math
import sys

import pandas as pd

from arcsem.report.collect import collect
from arcsem.report.paired import summary

REFS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5}
KEYS = {"in": "stage2.test.psnr_covered", "out": "stage2.test.psnr_uncovered", "all": "stage2.test.psnr"}


def runs_frame(paths: list[str]) -> pd.DataFrame:
    """One row per run: dataset, features, references count, seed and the held-out PSNRs."""
    df = collect(paths).runs
    if df.empty:
        raise SystemExit(f"no runs (metrics.json) under {paths}")
    refs = df.get("stage2.references")
    out = pd.DataFrame({
        "dataset": df.get("dataset.specimen", df.get("dataset", pd.Series(["?"] * len(df)))).fillna("grain"),
        "features": df.get("features"), "seed": pd.to_numeric(df["seed"], errors="coerce"),
        "refs": [len(r) if isinstance(r, list) else REFS.get(str(r), math.nan) for r in
                 (refs if refs is not None else df.get("colorize.references", [math.nan] * len(df)))],
        "coverage": pd.to_numeric(df.get("stage2.test.coverage"), errors="coerce"),
        "tcm": [("tcm" in v) if isinstance(v, list) else math.nan for v in df.get("stage2.losses", [[]] * len(df))],
        "ccm": [("ccm" in v) if isinstance(v, list) else math.nan for v in df.get("stage2.losses", [[]] * len(df))],
    })
    for k, col in KEYS.items():
        out[k] = pd.to_numeric(df.get(col), errors="coerce")
    return out[out["tcm"].eq(True) & out["ccm"].eq(True)]  # full model only


def _cell(v: pd.Series) -> str:
    v = v.dropna()
    if v.empty:
        return "n/a"
    return f"{v.mean():.2f} ± {v.std(ddof=1):.2f}" if len(v) > 1 else f"{v.mean():.2f}"


def table(df: pd.DataFrame) -> str:
    refs = sorted(df["refs"].dropna().unique())
    head = ["dataset", "features"] + [f"{int(r)} ref. {k} cov." for r in refs for k in ("in", "out")] + ["seeds"]
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for (ds, feat), sub in df.groupby(["dataset", "features"]):
        cells = [_cell(sub[sub["refs"] == r][k]) for r in refs for k in ("in", "out")]
        lines.append("| " + " | ".join([str(ds), str(feat)] + cells + [str(sub["seed"].nunique())]) + " |")
    cov = df.groupby(["dataset", "refs"])["coverage"].mean()
    lines.append("")
    lines.append("Held-out coverage (share of specimen pixels with a pseudo-colour): " + "; ".join(
        f"{ds} {int(r)} ref. {c:.3f}" for (ds, r), c in cov.items()))
    return "\n".join(lines) + "\n"


REGIONS = {"all": "whole image", "in": "in cov.", "out": "out cov."}


def paired(df: pd.DataFrame, base: str) -> str:
    """Each extractor minus ``base``, paired by seed, per dataset, references and region (:data:`REGIONS`):
    mean, 95 % t-interval and the seeds at which it is better."""
    lines = []
    for (ds, r), sub in df.groupby(["dataset", "refs"]):
        for region, name in REGIONS.items():
            wide = sub.pivot_table(index="seed", columns="features", values=region, aggfunc="first")
            if base not in wide:
                continue
            for feat in [c for c in wide.columns if c != base]:
                d = (wide[feat] - wide[base]).dropna()
                if len(d) >= 2:
                    s = summary(d, lower=False)
                    lines.append(f"{ds}, {int(r)} ref., {name}: {feat} - {base} {s['mean']:+.2f} dB "
                                 f"[{s['ci_low']:+.2f}, {s['ci_high']:+.2f}], better at {s['b_wins']}/{s['n']} seeds")
    return "\n".join(lines) + ("\n" if lines else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--out", default=None)
    ap.add_argument("--paired", default=None, help="compare every extractor with this one, paired by seed")
    a = ap.parse_args(argv)
    df = runs_frame(a.paths)
    text = table(df) + (("\n" + paired(df, a.paired)) if a.paired else "")
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
