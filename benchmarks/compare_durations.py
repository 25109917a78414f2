"""Test time of two commits, compared on the tests both have: the summed setup + call + teardown of each test ID
from two ``pytest --durations=0`` logs (issue 41's "make test not longer", side by side).

    (cd <old worktree> && .venv/bin/python -m pytest -q -p no:cacheprovider -n 2 --dist loadgroup --durations=0 \\
        -o addopts="" > /tmp/old.log)
    .venv/bin/python -m pytest ... --durations=0 -o addopts="" > /tmp/new.log        # the same command here
    .venv/bin/python benchmarks/compare_durations.py /tmp/old.log /tmp/new.log
"""
from __future__ import annotations

import re
import sys


def durations(path: str) -> dict[str, float]:
    """``{test id: seconds}`` summed over its setup, call and teardown lines (pytest hides those under 5 ms)."""
    out: dict[str, float] = {}
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            m = re.match(r"^([\d.]+)s (call|setup|teardown)\s+(\S+)", line)
            if m:
                out[m.group(3)] = out.get(m.group(3), 0.0) + float(m.group(1))
    return out


def main(old: str, new: str) -> None:
    a, b = durations(old), durations(new)
    common = set(a) & set(b)
    sa, sb = sum(a[k] for k in common), sum(b[k] for k in common)
    print(f"tests timed in both: {len(common)}; summed {sa:.1f} s -> {sb:.1f} s ({sb / max(sa, 1e-9):.3f}x)")
    print(f"only in the first: {sum(v for k, v in a.items() if k not in common):.1f} s; only in the second: "
          f"{sum(v for k, v in b.items() if k not in common):.1f} s")


if __name__ == "__main__":
    main(*sys.argv[1:3])
