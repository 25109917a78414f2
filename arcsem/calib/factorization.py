"""Initial cameras without stage angles: affine factorisation (Tomasi & Kanade 1992) and resection.

1. The largest block of views that share tracks: greedily, from the view with the most tracks, add the view
   that keeps the most tracks common to all chosen views (at least :data:`MIN_COMMON`).
2. The centred measurement matrix ``W [2F, P]`` of that block has rank 3: ``W = M S`` by SVD, up to an
   invertible ``Q``. The metric upgrade asks every view's two rows ``a, b`` of ``M Q`` to be orthogonal with
   norm ``s`` (the known pixels per world unit): linear in the symmetric ``L = Q Q^T``. An indefinite ``L``
   (too little tilt between the views) is clamped to the nearest positive semi-definite matrix.
3. Every other view is resected from the points it sees (an affine 2 x 4 camera by least squares, then the
   nearest scaled rotation), and new tracks are triangulated, until every connected view is placed.

The result is defined up to the depth reversal of parallel projection (``X -> -X``, each ``R -> diag(-1,-1,1) R``);
:mod:`.frame` picks the one with the substrate behind the specimen.
"""
from __future__ import annotations

import numpy as np

from ..errors import DataError
from .bundle import OrthoViews
from .geometry import triangulate
from .tracks import Observations

__all__ = ["MIN_COMMON", "init_factorization"]

MIN_COMMON = 8


def _block(vis: np.ndarray) -> list[int]:
    """Greedy largest block of views sharing at least MIN_COMMON tracks (``vis [V, N]`` bool)."""
    chosen = [int(vis.sum(1).argmax())]
    common = vis[chosen[0]].copy()
    while True:
        rest = [v for v in range(len(vis)) if v not in chosen]
        if not rest:
            return chosen
        gains = [(int((common & vis[v]).sum()), v) for v in rest]
        n, v = max(gains)
        if n < MIN_COMMON:
            return chosen
        chosen.append(v)
        common &= vis[v]


def _metric(M: np.ndarray, s: float) -> np.ndarray:
    """``Q [3, 3]`` with ``M Q`` rows ``a, b`` per view orthogonal, of norm ``s`` (``M [2F, 3]``)."""
    def row(a, b):  # coefficients of a L b^T in the 6 entries of a symmetric L
        return np.array([a[0] * b[0], a[1] * b[1], a[2] * b[2], a[0] * b[1] + a[1] * b[0],
                         a[0] * b[2] + a[2] * b[0], a[1] * b[2] + a[2] * b[1]])

    rows, rhs = [], []
    for f in range(len(M) // 2):
        a, b = M[2 * f], M[2 * f + 1]
        rows += [row(a, a), row(b, b), row(a, b)]
        rhs += [s * s, s * s, 0.0]
    l = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
    L = np.array([[l[0], l[3], l[4]], [l[3], l[1], l[5]], [l[4], l[5], l[2]]])
    w, U = np.linalg.eigh(L)
    w = np.maximum(w, 1e-6 * max(w.max(), 1e-12))
    return U * np.sqrt(w)


def _scaled_rotation(A: np.ndarray) -> np.ndarray:
    """The rotation ``[3, 3]`` whose first two rows are nearest to the rows of ``A [2, 3]`` (up to scale)."""
    U, _, Vt = np.linalg.svd(A, full_matrices=False)
    r = U @ Vt
    return np.vstack([r, np.cross(r[0], r[1])])


def _resect(obs: Observations, v: int, X: np.ndarray, known: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of view ``v`` from its observations of points ``known``."""
    sel = (obs.vi == v) & known[obs.pj]
    P, u = X[obs.pj[sel]], obs.uv[sel]
    A = np.linalg.lstsq(np.c_[P, np.ones(len(P))], u, rcond=None)[0].T    # [2, 4]
    R = _scaled_rotation(A[:, :3])
    t = (u - s * P @ R[:2].T).mean(0)
    return R, t


def init_factorization(obs: Observations, n_views: int, s: float) -> tuple[OrthoViews, np.ndarray, list[int]]:
    """Views and points for ``obs`` without stage angles (module docstring); returns the factorised block too."""
    vis = np.zeros((n_views, obs.n_points), bool)
    vis[obs.vi, obs.pj] = True
    block = _block(vis)
    if len(block) < 3:
        raise DataError(f"affine factorisation needs three views that share {MIN_COMMON} tracks; the best block has "
                        f"{len(block)} view(s): give the stage tilts (--tilts)")
    common = np.nonzero(vis[block].all(0))[0]
    lookup = {(int(v), int(p)): k for k, (v, p) in enumerate(zip(obs.vi, obs.pj))}
    W = np.stack([obs.uv[[lookup[(v, int(p))] for p in common]] for v in block])   # [F, P, 2]
    centre = W.mean(1)
    Wc = (W - centre[:, None]).transpose(0, 2, 1).reshape(2 * len(block), len(common))
    U, S, Vt = np.linalg.svd(Wc, full_matrices=False)
    M, Sh = U[:, :3] * np.sqrt(S[:3]), np.sqrt(S[:3])[:, None] * Vt[:3]
    Q = _metric(M, s)
    M, Sh = M @ Q, np.linalg.solve(Q, Sh)
    R = np.tile(np.eye(3), (n_views, 1, 1))
    t = np.zeros((n_views, 2))
    placed = np.zeros(n_views, bool)
    for f, v in enumerate(block):
        R[v] = _scaled_rotation(M[2 * f: 2 * f + 2])
        t[v] = centre[f]
        placed[v] = True
    X = np.zeros((obs.n_points, 3))
    X[common] = Sh.T
    known = np.zeros(obs.n_points, bool)
    known[common] = True
    views, X = _grow(obs, R, t, np.full(n_views, s), X, known, placed)
    return views, X, block


def _grow(obs, R, t, scale, X, known, placed) -> tuple[OrthoViews, np.ndarray]:
    """Resect the remaining views and triangulate their tracks, the best-connected view first."""
    while True:
        seen = np.bincount(obs.vi[known[obs.pj]], minlength=len(R))
        seen[placed] = -1
        v = int(seen.argmax())
        if seen[v] < 6:
            break
        R[v], t[v] = _resect(obs, v, X, known, scale[0])
        placed[v] = True
        _retriangulate(obs, R, t, scale, X, known, placed)
    _retriangulate(obs, R, t, scale, X, known, placed)
    if not placed.all():
        raise DataError(f"view(s) {', '.join(str(int(v)) for v in np.nonzero(~placed)[0])} could not be placed "
                        "from the tracks they share with the others")
    return OrthoViews(R, t, scale), X


def _retriangulate(obs, R, t, scale, X, known, placed) -> None:
    """Triangulate every track seen by two or more placed views (in place)."""
    sel = placed[obs.vi]
    n_seen = np.bincount(obs.pj[sel], minlength=obs.n_points)
    Xn = triangulate(R, t, scale, obs.vi[sel], obs.pj[sel], obs.uv[sel], obs.n_points)
    ok = n_seen >= 2
    X[ok] = Xn[ok]
    known |= ok
