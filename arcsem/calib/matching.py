"""Pairwise matching: mutual nearest neighbours with Lowe's ratio test, verified by the affine fundamental matrix.

Two orthographic (affine) views of a rigid scene satisfy ``a u' + b v' + c u + d v + e = 0`` for every
match: the 4-vectors ``(u, v, u', v')`` lie on one hyperplane, and its unit normal ``n`` gives the affine
fundamental matrix. Fitting the plane by total least squares (the smallest singular vector of the centred
points) minimises the geometric error exactly, and ``|n . (r - centre)|`` is a match's distance to it in
pixels. RANSAC draws minimal sets of four matches (Hartley & Zisserman, ch. 14).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairMatches", "affine_fundamental", "match_descriptors", "ransac_affine_fundamental"]


@dataclass
class PairMatches:
    """Verified matches of views ``a < b``: feature indices ``ia, ib [m]``; ``normal [4]`` of the fitted
    affine epipolar hyperplane (``(a, b)`` of image b, ``(c, d)`` of image a: the epipolar line normals)."""

    a: int
    b: int
    ia: np.ndarray
    ib: np.ndarray
    normal: np.ndarray


def _dist(sim: np.ndarray) -> np.ndarray:
    """Euclidean distance of unit vectors from their dot product."""
    return np.sqrt(np.maximum(2.0 - 2.0 * sim, 0.0))


def _second(q: np.ndarray, base: np.ndarray, best: np.ndarray) -> np.ndarray:
    """Second-largest dot product of each row of ``q [m, D]`` with ``base [N, D]`` (its largest is at ``best``)."""
    sim = q @ base.T
    sim[np.arange(len(q)), best] = -np.inf
    return sim.max(1)


def _nearest(q: np.ndarray, base: np.ndarray, chunk: int) -> np.ndarray:
    """Index of the most similar row of ``base [N, D]`` for each row of ``q [M, D]`` (blocks of ``chunk`` rows)."""
    return np.concatenate([(q[s:s + chunk] @ base.T).argmax(1) for s in range(0, len(q), chunk)])


def match_descriptors(da: np.ndarray, db: np.ndarray, ratio: float = 0.8, chunk: int = 4096
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours of unit descriptors ``da [Na, D]``, ``db [Nb, D]`` that pass the ratio test
    (``d1 < ratio d2`` in both directions); returns index arrays ``ia, ib``.

    Nearest neighbours both ways (row arg-max of two products, in blocks of ``chunk`` rows), then the
    second-best distances of the mutual pairs only."""
    if len(da) < 2 or len(db) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    row_best, col_best = _nearest(da, db, chunk), _nearest(db, da, chunk)
    ia = np.nonzero(col_best[row_best] == np.arange(len(da)))[0]
    ib = row_best[ia]
    d1 = _dist(np.einsum("ij,ij->i", da[ia], db[ib]))
    keep = (d1 < ratio * _dist(_second(da[ia], db, ib))) & (d1 < ratio * _dist(_second(db[ib], da, ia)))
    return ia[keep], ib[keep]


def affine_fundamental(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares hyperplane of 4-vectors ``r [m, 4]``: unit ``normal [4]`` and ``centre [4]``."""
    centre = r.mean(0)
    return np.linalg.svd(r - centre, full_matrices=False)[2][-1], centre


def ransac_affine_fundamental(xa: np.ndarray, xb: np.ndarray, threshold: float, iters: int = 512,
                              seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Inlier mask ``[m]`` and plane normal ``[4]`` of matches ``xa, xb [m, 2]`` (see the module docstring).

    ``threshold``: largest distance (pixels) of an inlier to the hyperplane.
    """
    r = np.concatenate([xa, xb], 1)
    m = len(r)
    if m < 5:
        return np.zeros(m, bool), np.zeros(4)
    rng = np.random.default_rng(seed)
    sample = r[rng.integers(0, m, size=(iters, 4))]                        # [I, 4, 4]
    centre = sample.mean(1, keepdims=True)
    normals = np.linalg.svd(sample - centre)[2][:, -1]                     # [I, 4]
    dist = np.abs(np.einsum("mk,ik->im", r, normals) - np.einsum("ik,ik->i", centre[:, 0], normals)[:, None])
    inliers = dist < threshold
    best = inliers[int(inliers.sum(1).argmax())]
    normal = np.zeros(4)
    for _ in range(3):  # refit on the inliers, re-select
        if best.sum() < 5:
            break
        normal, c = affine_fundamental(r[best])
        best = np.abs((r - c) @ normal) < threshold
    return best, normal
