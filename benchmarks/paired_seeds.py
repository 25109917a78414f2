"""Is row B better than row A? Paired by seed, with a confidence interval.

Two rows of a study (e.g. ``gs2d`` and ``gs2d_act`` of the grayscale comparison) trained with the
same seeds start alike (initial points, view order), so the question "is B better?" is asked of the
per-seed differences B - A: their mean and its t-interval say whether the difference stands out of the
run-to-run noise. (Pairing helps only as far as the seed's luck is shared: on the built-in scene's
2DGS rows the differences vary as much as the rows themselves, since densification soon makes the
runs diverge.) This script pairs the runs found under the given folders
(runs or Hydra sweep folders, read by ``arcsem.report.collect``) by seed and prints, per metric, each
seed's difference B - A, their mean, standard deviation, a two-sided 95 % t-interval of the mean,
and how many seeds B won (for an error metric, "won" means lower).

Usage::

    .venv/bin/python benchmarks/paired_seeds.py SWEEP_OR_RUN [...] --a gs2d --b gs2d_act \\
        [--metrics stage1.test.psnr stage1.test.ssim stage1.depth.test_mae_pct]

A seed with a run of one row but not the other is listed and left out; two runs of the same row and
seed (e.g. the same sweep passed twice) are an error naming both folders.
"""
from __future__ import annotations

import argparse
import sys

from arcsem.errors import DataError
from arcsem.report.collect import collect
from arcsem.report.paired import describe, lower_is_better, pair, summary

DEFAULT_METRICS = ["stage1.test.psnr", "stage1.test.ssim", "stage1.depth.test_mae_pct"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", help="run or sweep folders")
    ap.add_argument("--a", required=True, help="baseline row (e.g. gs2d)")
    ap.add_argument("--b", required=True, help="compared row (e.g. gs2d_act)")
    ap.add_argument("--metrics", nargs="+", default=DEFAULT_METRICS)
    args = ap.parse_args(argv)
    try:
        return report(args)
    except DataError as err:  # missing folder, metric or row: one line, no traceback
        raise SystemExit(f"paired_seeds: {err}") from None


def report(args: argparse.Namespace) -> int:
    """Print the paired table and summary of every metric."""
    df = collect(args.paths).runs
    if df.empty:
        raise SystemExit(f"no runs (metrics.json) under {args.paths}")
    for metric in args.metrics:
        table, unpaired = pair(df, args.a, args.b, metric)
        low = lower_is_better(metric)
        print(f"\n{metric} ({'lower' if low else 'higher'} is better): {args.b} - {args.a}, by seed")
        print(table.to_string(float_format=lambda x: f"{x:.4f}"))
        if unpaired:
            print(f"  left out (one row only): seeds {unpaired}")
        print("  " + describe(summary(table["delta"], low), args.b))
    return 0


if __name__ == "__main__":
    sys.exit(main())
