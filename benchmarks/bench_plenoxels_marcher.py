"""The Plenoxels fused ray marcher against the one before issue 20, side by side in one process.

The old kernel is built from git (``--old-ref``, default: the last commit before the new marcher) under its
own extension name through :mod:`arcsem.cext`. Both march the same 5000 random rays of 8 views (256x192,
cameras at 2.6 half-box lengths) through the same grid; a call is forward + backward (gradients of density,
SH) of the kernel alone, the new one including its live masks (they follow the density every step); the
old one's cell occupancy depends on the index only and is computed once, outside the timing. Calls
alternate old/new; the figure is the median of ``runs``. Grid states (all with SH degree 2, random SH):

* ``init``: every point stored, density 0.1: svox2's start (nothing to skip, no ray ends early);
* ``ball``: every point stored, density 200 inside a ball of radius 0.6 (half-box units), -1 outside: a
  trained grid before pruning (empty space carved to negative density);
* ``shell``: ``ball`` pruned to the points within 3 voxels of the sphere (what weight pruning keeps).

    .venv/bin/python benchmarks/bench_plenoxels_marcher.py --threads 1 --runs 7
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

OLD_REF = "48f38bffa42aadcd855a1ab188ba09992b2d48a7"  # main before the new marcher (issue 20)
GRIDS = {"quick": [128, 128, 96], "paper": [304, 304, 128]}
STATES = ("init", "ball", "shell")
ROOT = Path(__file__).resolve().parents[1]


def old_kernel(ref: str):
    """The old fused marcher built from ``git show ref:backbones/plenoxels/cpp/render.cpp``."""
    from arcsem import cext

    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{ref}:backbones/plenoxels/cpp/render.cpp"],
                         capture_output=True, text=True, check=True).stdout
    cache = Path(os.environ.get("ARCSEM_CACHE", Path.home() / ".cache" / "arcsem"))
    folder = cache / "bench" / f"plenoxels_old_{ref[:12]}"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "render_old.cpp"
    if not path.is_file() or path.read_text() != src:
        path.write_text(src)
    mod = cext.load(cext.Extension(prefix="arcsem_plenoxels_old", sources=(path,), what="old Plenoxels marcher"))
    if mod is None:
        raise SystemExit("error: the old kernel did not build (see the warning above)")
    return mod


def make_grid(reso: list[int], state: str, gen: torch.Generator):
    """``index [X,Y,Z]``, ``density [M]``, ``sh [M, 9, 3]`` of a grid in ``state`` over the box [-1, 1]^3."""
    from arcsem.backbones.plenoxels.grid import build_index

    axes = [torch.linspace(-1, 1, r) for r in reso]
    r = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).norm(dim=-1)
    vox = 2.0 / (min(reso) - 1)
    occ = (r - 0.6).abs() < 3 * vox if state == "shell" else torch.ones(reso, dtype=torch.bool)
    index = build_index(occ)
    if state == "init":
        dens = torch.full((int(occ.sum()),), 0.1)
    else:
        dens = torch.where(r[occ] < 0.6, 200.0, -1.0)
    return index, dens, 0.1 * torch.randn(int(occ.sum()), 9, 3, generator=gen)


def rays(n: int, gen: torch.Generator):
    """``n`` random rays ``o, d [n, 3]`` of the 8 views of bench_plenoxels.scene()."""
    from bench_plenoxels import scene

    cams = scene().train.cameras
    o, d = cams.rays()
    sel = torch.randint(0, o.reshape(-1, 3).shape[0], (n,), generator=gen)
    return o.reshape(-1, 3)[sel].contiguous(), d.reshape(-1, 3)[sel].contiguous()


def calls(old, index, dens, sh, o, d, bounds, step):
    """Two closures, one kernel call (forward + backward) each: old and new."""
    from arcsem.backbones.plenoxels import fused
    from arcsem.backbones.plenoxels.grid import cell_occupancy, occupied_coords

    new = fused.load_extension()
    cell_occ = cell_occupancy(index).contiguous().view(torch.uint8)
    coords = occupied_coords(index)
    empty = torch.zeros(0)
    g = [torch.randn(o.shape[0], 3), torch.randn(o.shape[0]), torch.zeros(o.shape[0])]
    common = (step, 1.0, 1e-4, 2, False)
    big = float(1 << 30)  # the old kernel's private-buffer limit (bytes): per-thread gradient buffers

    def run_old():
        args = (o, d, index, cell_occ, dens, sh, empty, empty, bounds, *common)
        out = old.forward(*args)
        return old.backward(*args, *out, *g, big), out

    def run_new():
        live = new.live(index, coords, dens, fused.SKIP_SHIFT)
        args = fused.structs(o, d, index, live, bounds, dens, sh, empty, empty, shift=fused.SKIP_SHIFT, step=step,
                             scale=1.0, stop=1e-4, degree=2, act=False)
        out = new.forward(*args)
        g_mom = torch.zeros(o.shape[0], 2)  # the distortion's moments (an output since 2026-11-25): unused here
        grads = fused.struct("Marched", rgb=g[0], alpha=g[1], wt=g[2], mom=g_mom)
        res = new.backward(*args, out, grads, fused.slots(dens.shape[0]))
        return (res.rows, res.density, res.sh), (out.rgb, out.alpha, out.wt)  # sparse: rows, d, SH

    return run_old, run_new


def side_by_side(old, reso, state, runs, n_rays=5000):
    gen = torch.Generator().manual_seed(0)
    index, dens, sh = make_grid(reso, state, gen)
    o, d = rays(n_rays, gen)
    bounds = torch.tensor([[-1.0] * 3, [1.0] * 3])
    step = 0.5 * 2.0 / (max(reso) - 1)  # 0.5 of the smallest voxel side
    run_old, run_new = calls(old, index, dens, sh, o, d, bounds, step)
    (go, out_o), ((rows, gd, gsh), out_n) = run_old(), run_new()  # warm-up, and both must agree
    gn = [torch.zeros_like(dens).index_copy_(0, rows, gd), torch.zeros_like(sh).index_copy_(0, rows, gsh)]
    for a, b in zip([*out_o, *go[:2]], [*out_n, *gn]):
        torch.testing.assert_close(b, a, atol=2e-4, rtol=2e-3)
    times = {"old": [], "new": []}
    for _ in range(runs):
        for name, fn in (("old", run_old), ("new", run_new)):
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    med = {k: statistics.median(v) for k, v in times.items()}
    alpha = float(out_n[1].mean())
    return {"grid": "x".join(map(str, reso)), "state": state, "voxels": int(dens.numel()), "mean_alpha": alpha,
            "old": n_rays / med["old"], "new": n_rays / med["new"], "ratio": med["old"] / med["new"]}


def run_marcher(runs: int = 7, threads: int = 1, ref: str | None = None) -> list[dict]:
    torch.set_num_threads(threads)
    old = old_kernel(ref or OLD_REF)
    rows = []
    print(f"{'grid':>12} {'state':>6} {'voxels':>9} {'alpha':>6} {'old rays/s':>11} {'new rays/s':>11} {'new/old':>8}")
    for name, reso in GRIDS.items():
        for state in STATES:
            r = side_by_side(old, reso, state, runs)
            rows.append(r)
            print(f"{r['grid']:>12} {state:>6} {r['voxels']:>9} {r['mean_alpha']:6.3f} {r['old']:11.0f} "
                  f"{r['new']:11.0f} {r['ratio']:7.1f}x  ({name} grid)", flush=True)
    load = os.getloadavg()
    print(f"forward + backward of 5000 rays per call, median of {runs} alternating calls; threads {threads}; "
          f"torch {torch.__version__}; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; old kernel: "
          f"{(ref or OLD_REF)[:12]}")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--old-ref", default=None, help=f"git revision of the old kernel (default {OLD_REF[:12]})")
    a = ap.parse_args()
    run_marcher(a.runs, a.threads, a.old_ref)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()
