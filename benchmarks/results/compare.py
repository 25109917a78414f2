"""Compare two generated study tables (``<study>.csv`` from arcsem-report): per metric, the largest
absolute difference between rows of the same key, to state run-to-run noise of a rerun.

    .venv/bin/python benchmarks/results/compare.py benchmarks/results/reference_count/reference_count.csv \
        /tmp/rerun/reference_count.csv
"""
from __future__ import annotations

import argparse
import sys

import pandas as pd


def compare(a: pd.DataFrame, b: pd.DataFrame) -> pd.DataFrame:
    """``[metric, max_abs_diff, row]`` over the rows both tables have (``.std`` columns skipped)."""
    m = a.merge(b, on="row", suffixes=("_a", "_b"))
    metrics = [c for c in a.columns if c.startswith("stage") and not c.endswith(".std") and c + "_b" in m]
    out = []
    for c in metrics:
        d = (pd.to_numeric(m[c + "_a"], errors="coerce") - pd.to_numeric(m[c + "_b"], errors="coerce")).abs()
        if d.notna().any():
            out.append({"metric": c, "max_abs_diff": float(d.max()), "row": m["row"][d.idxmax()]})
    return pd.DataFrame(out, columns=["metric", "max_abs_diff", "row"])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a")
    p.add_argument("b")
    args = p.parse_args(argv)
    res = compare(pd.read_csv(args.a), pd.read_csv(args.b))
    print(res.to_string(index=False) if len(res) else "no common rows/metrics")
    return 0


if __name__ == "__main__":
    sys.exit(main())
