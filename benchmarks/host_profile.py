"""Where a whole job's wall time goes on the host: a py-spy profile (``-f raw``) summed by function.

    py-spy record --nonblocking -r 50 -f raw -o /tmp/demo.pyspy -- arcsem experiment=demo ...
    .venv/bin/python benchmarks/host_profile.py /tmp/demo.pyspy [--rate 50] [--top 40] [--all]

Prints the seconds each function was on the stack (inclusive: once a sample however deep it recurs), the project's
own functions (``arcsem/``, ``backbones/``, ``losses/``) unless ``--all``, most first; then the same for the phases a
run reports (the ``timing.phase`` blocks of the stages and what they call: ``train``, ``turntable``,
``export_mesh``, ``evaluate_split``, ...). ``py-spy`` samples every thread: with ``--nonblocking`` it does not stop
the job to read it, so the job's own timings stay as they are (benchmarks/gpu_check.sh runs the GPU demo this way
with ``DEMO_PYSPY=1``; ``--idle`` is not given, so seconds are those with the thread running or waiting on a lock,
an I/O or a CUDA synchronisation).
"""
from __future__ import annotations

import argparse
import collections
import re
from pathlib import Path

OWN = re.compile(r"(^|/)(arcsem|backbones|losses)/")
PHASES = ("run_stage1", "run_stage2", "train", "evaluate", "evaluate_split", "evaluate_colour", "turntable",
          "write_outputs", "write_products", "write_colored_products", "export_mesh", "fuse_views", "validate",
          "_guide_factory", "pseudo_colors", "write_report", "build_report", "load_scene", "_find_and_load")


def frames(stack: str) -> list[tuple[str, str]]:
    """``[(function, file), ...]`` outermost first, from one line of py-spy's raw (collapsed-stack) output."""
    out = []
    for f in stack.split(";"):
        name, _, where = f.partition(" (")
        out.append((name.strip(), where.rsplit(":", 1)[0].rstrip(")")))
    return out


def inclusive(path: Path, own_only: bool) -> tuple[collections.Counter, int]:
    """Samples a function was on the stack (``function (file)`` -> count) and the total samples."""
    counts: collections.Counter = collections.Counter()
    total = 0
    for line in path.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if not n.isdigit():
            continue
        total += int(n)
        seen = set()
        for name, where in frames(stack):
            if own_only and not OWN.search(where) and name != "_find_and_load":
                continue
            key = f"{name} ({re.sub(r'.*/(arcsem|backbones|losses|site-packages)/', '', where)})"
            if key not in seen:
                seen.add(key)
                counts[key] += int(n)
    return counts, total


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("raw", type=Path)
    ap.add_argument("--rate", type=float, default=50.0, help="py-spy's samples a second (-r)")
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--all", action="store_true", help="every function, not only the project's")
    a = ap.parse_args(argv)
    counts, total = inclusive(a.raw, own_only=not a.all)
    print(f"{a.raw}: {total} samples = {total / a.rate:.1f} s of sampled thread time\n")
    print("| seconds | share | function (file) |\n|---:|---:|---|")
    for key, n in counts.most_common(a.top):
        print(f"| {n / a.rate:.1f} | {100 * n / max(total, 1):.0f} % | {key} |")
    print("\nPhases (the functions the stages time, and imports):\n\n| seconds | function (file) |\n|---:|---|")
    for key, n in sorted(counts.items(), key=lambda kv: -kv[1]):
        if key.split(" (")[0] in PHASES:
            print(f"| {n / a.rate:.1f} | {key} |")


if __name__ == "__main__":
    main()
