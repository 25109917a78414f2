"""The surface spread's linear solve: SuperLU (what :func:`arcsem.colorize.surface.harmonic_solve` uses) against
conjugate gradients with a Jacobi preconditioner, on graphs shaped like the surface graph.

A graph of ``N`` points on a sphere (a surface), each joined to its 12 nearest neighbours with weights
``exp(-(d / mean d)^2) * exp(-(dg / 0.05)^2)`` of the distance and of a random grey level (the surface graph's grey
term, the same 0.05 scale), the cap ``z > 0.6`` known (four random values a node, the scribbles). Prints the time of
each solver, CG's iterations per column and the largest difference of the two answers::

    .venv/bin/python benchmarks/harmonic_solve.py [--nodes 50000 200000] [--rtol 1e-10]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import cg
from scipy.spatial import cKDTree

from arcsem.colorize.surface import harmonic_solve


def graph(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    grey = rng.random(n)
    d, j = cKDTree(p).query(p, 13)
    d, j = d[:, 1:].reshape(-1), j[:, 1:].reshape(-1)
    i = np.repeat(np.arange(n), 12)
    w = np.exp(-(d / d.mean()) ** 2) * np.exp(-((grey[i] - grey[j]) / 0.05) ** 2) + 1e-6
    W = coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    known = np.flatnonzero(p[:, 2] > 0.6)
    return W.maximum(W.T), known, rng.random((len(known), 4))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, nargs="+", default=[50_000, 200_000])
    ap.add_argument("--rtol", type=float, default=1e-10)
    args = ap.parse_args()
    for n in args.nodes:
        W, known, values = graph(n)
        t0 = time.perf_counter()
        x, _ = harmonic_solve(W, known, values)
        t_lu = time.perf_counter() - t0
        unknown = np.setdiff1d(np.arange(n), known)
        L = (diags(np.asarray(W.sum(1)).reshape(-1)) - W).tocsr()
        Luu, rhs = L[unknown][:, unknown].tocsr(), -(L[unknown][:, known] @ values)
        t0 = time.perf_counter()
        jacobi, cols, iters = diags(1.0 / Luu.diagonal()), [], []
        for c in range(rhs.shape[1]):
            count = [0]
            sol, _ = cg(Luu, rhs[:, c], M=jacobi, rtol=args.rtol, maxiter=50_000,
                        callback=lambda _x, k=count: k.__setitem__(0, k[0] + 1))
            cols.append(sol)
            iters.append(count[0])
        t_cg = time.perf_counter() - t0
        diff = float(np.abs(np.stack(cols, 1) - x[unknown]).max())
        print(f"{n} nodes: SuperLU {t_lu:.2f} s; CG (Jacobi) {t_cg:.2f} s, iterations {iters}, largest difference "
              f"{diff:.1e}", flush=True)


if __name__ == "__main__":
    main()
