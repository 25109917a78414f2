"""Time generating the built-in synthetic scene (default size: SceneParams, 288x192; 40 views) with arcsem.synthetic.

Usage: .venv/bin/python benchmarks/bench_synthetic.py [--repeats 3] [--width 288 --height 192]
Prints every run, the median, and the ratio to a run without anti-aliasing (supersample=1).
Requirement (issue 3): the default scene in under 60 s on the 2-core development machine.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from arcsem.synthetic import SceneParams, generate_scene


def time_once(**params) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_scene(Path(tmp) / "scene", **params)
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--width", type=int, default=SceneParams.width)
    ap.add_argument("--height", type=int, default=SceneParams.height)
    ap.add_argument("--camera", default=SceneParams.camera)
    ap.add_argument("--no-compare", action="store_true", help="skip the supersample=1 comparison")
    args = ap.parse_args()
    base = {"width": args.width, "height": args.height, "camera": args.camera}
    rows = [("default (supersample=2)", base)]
    if not args.no_compare:
        rows.append(("no anti-aliasing (supersample=1)", {**base, "supersample": 1}))
    medians = {}
    for label, params in rows:
        runs = [time_once(**params) for _ in range(args.repeats)]
        medians[label] = statistics.median(runs)
        print(f"{label:34s} runs: {', '.join(f'{r:.1f}' for r in runs)} s   median {medians[label]:.1f} s")
    first = medians[rows[0][0]]
    for label, m in medians.items():
        print(f"{label:34s} {m:6.1f} s   ratio to default {m / first:.2f}")
    print(f"scene {args.width}x{args.height} {args.camera}, 40 views; limit 60 s: "
          f"{'PASS' if first < 60 else 'FAIL'}")


if __name__ == "__main__":
    main()
