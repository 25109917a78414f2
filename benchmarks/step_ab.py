"""Stage-1 training speed of two checkouts side by side: the real ``arcsem`` command of each, run alternately.

Each checkout has its own virtual environment (``<tree>/.venv``, an editable install of that tree: ``make setup``
there). One run = ``arcsem stage=gray`` on the built-in scene for ``--steps`` steps; the figure is the run's own
``stage1.steps_per_s`` (training steps only: no evaluation, export or start-up). Runs alternate (A, B, A, B, ...)
so that both see the same machine load; the table gives each tree's median seconds per step and their ratio.

    git worktree add /tmp/base 48f38bf && (cd /tmp/base && make setup)
    .venv/bin/python benchmarks/step_ab.py --trees /tmp/base . --repeats 3 [--threads 2] [-- extra overrides]

    git worktree add /tmp/base 48f38bf          # or: both trees run with this checkout's environment
    .venv/bin/python benchmarks/step_ab.py --shared-venv --trees /tmp/base . --repeats 3

``--busy K`` starts K busy processes (a pure-Python loop each) beside every run: the contention figure of
issue 21 (``--trees . --busy 0``, then ``--busy 1`` and ``--busy 2``).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OVERRIDES = ["stage=gray", "dataset=synthetic", "backbone=gs2d", "act=paper", "train=quick", "train.eval.lpips=false",
             "train.eval.video=false", "mesh.enabled=false", "train.progress=false", "report=false"]


def run_once(tree: Path, steps: int, threads: int, extra: list[str], busy: int, shared: bool = False) -> float:
    """Seconds per training step of one ``arcsem`` run in ``tree`` (beside ``busy`` busy processes); ``shared``: with
    this checkout's virtual environment (benchmarks/shared_venv/sitecustomize.py), not the tree's own."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    env = {**os.environ, "TQDM_DISABLE": "1"}
    venv = tree / ".venv"
    if shared:
        venv = ROOT / ".venv"
        env.update(ARCSEM_ROOT=str(tree), PYTHONPATH=str(ROOT / "benchmarks" / "shared_venv"))
    try:
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [str(venv / "bin" / "arcsem"), *OVERRIDES, f"train.steps={steps}", f"threads={threads}",
                   f"hydra.run.dir={tmp}/run", *extra]
            subprocess.run(cmd, check=True, cwd=tree, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
            return 1.0 / json.loads((Path(tmp) / "run" / "metrics.json").read_text())["stage1"]["steps_per_s"]
    finally:
        for h in hogs:
            h.kill()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trees", nargs="+", type=Path, default=[Path(".")])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--busy", type=int, default=0)
    ap.add_argument("--shared-venv", action="store_true", help="run every tree with this checkout's .venv")
    args, extra = ap.parse_known_args()
    extra = [e for e in extra if e != "--"]
    times: dict[Path, list[float]] = {t: [] for t in args.trees}
    for k in range(args.repeats):
        for tree in args.trees:
            times[tree].append(run_once(tree.resolve(), args.steps, args.threads, extra, args.busy, args.shared_venv))
            print(f"repeat {k + 1}: {tree}: {times[tree][-1]:.4f} s/step", flush=True)
    first = statistics.median(times[args.trees[0]])
    print(f"\n{args.steps} steps, threads {args.threads}, {args.busy} busy process(es) beside; median of {args.repeats}")
    print("| tree | s/step (median) | runs | speed-up vs first |")
    print("|---|---:|---|---:|")
    for tree, ts in times.items():
        med = statistics.median(ts)
        print(f"| {tree} | {med:.4f} | {', '.join(f'{t:.4f}' for t in ts)} | {first / med:.2f}x |")
    print(f"load average {os.getloadavg()}; {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
