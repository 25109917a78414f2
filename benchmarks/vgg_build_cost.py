"""Seconds to build the TCM/CCM VGG extractor in a fresh interpreter (``torch`` already imported), and whether that
imported torchvision: what stage 2 pays once per process for it. Run it with each checkout's Python, alternately,
to compare two commits (0e143c6 builds the layers itself instead of importing torchvision)::

    python benchmarks/vgg_build_cost.py [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

CHILD = """
import logging, sys, time
import torch
logging.disable(logging.WARNING)  # the random-weights warning
t0 = time.perf_counter()
from arcsem.colorize.vgg import get_vgg
get_vgg("vgg16")
print(time.perf_counter() - t0, "torchvision" in sys.modules)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    runs = []
    for _ in range(a.repeats):
        out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True)
        secs, tv = out.stdout.split()[-2:]
        runs.append(float(secs))
    print(f"get_vgg('vgg16') in a fresh process: median {statistics.median(runs):.2f} s "
          f"({', '.join(f'{r:.2f}' for r in runs)}); torchvision imported: {tv}")


if __name__ == "__main__":
    main()
