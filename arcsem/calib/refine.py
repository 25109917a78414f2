"""Sub-pixel refinement of track observations at full resolution (affine Lucas-Kanade with gain and offset).

SIFT places a keypoint to a few tenths of a pixel of the copy it ran on, independently in every view. Here
each track keeps one reference observation (the one in its middle view, file order) and every other
observation is moved to where the reference's patch (15 x 15 pixels of the feature copy) fits best in its own view
under an affine warp ``x = b + A p`` with a brightness model ``g T + o`` (SEM exposure varies between
images). Both images are band-passed first (difference of Gaussians, sigma 1 and 2 pixels): the shading of
an SEM image changes smoothly with the viewing direction (secondary-electron yield, detector), and on the
synthetic scene the band-passed views agree locally to a median 0.06-0.10 px under the true geometry,
against 0.20 px for the lightly smoothed ones (576 x 384, texture 0.6; benchmarks/results/calibration.md). Gauss-Newton on the 8 unknowns of each observation, all observations at once (in chunks).
An observation whose fit moved more than ``max_shift`` pixels, whose warp is degenerate or whose
normalised correlation stays below ``min_ncc`` is dropped, and so is one seen more than ``max_angle`` degrees
away from its reference (given the views' directions).
"""
from __future__ import annotations

import numpy as np

from .tracks import Observations

__all__ = ["refine_observations"]


def _smooth(img: np.ndarray, sigma: float, band: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Band-passed float32 image (Gaussian ``sigma`` minus Gaussian ``band * sigma``) and its x / y
    central-difference gradients."""
    import cv2

    f = img.astype(np.float32)
    f = cv2.GaussianBlur(f, (0, 0), sigma) - cv2.GaussianBlur(f, (0, 0), band * sigma)
    gx = np.zeros_like(f)
    gy = np.zeros_like(f)
    gx[:, 1:-1] = 0.5 * (f[:, 2:] - f[:, :-2])
    gy[1:-1] = 0.5 * (f[2:] - f[:-2])
    return f, gx, gy


def _bilinear(imgs: tuple[np.ndarray, ...], x: np.ndarray, y: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Sample every image of ``imgs`` (one size) at pixel-centre coordinates ``x, y`` (arcsem convention);
    returns the samples and an in-bounds mask."""
    H, W = imgs[0].shape
    xc, yc = x - 0.5, y - 0.5                                   # array indices
    inside = (xc >= 0) & (yc >= 0) & (xc <= W - 1.001) & (yc <= H - 1.001)
    xc, yc = np.clip(xc, 0, W - 1.001), np.clip(yc, 0, H - 1.001)
    x0, y0 = np.floor(xc).astype(np.int64), np.floor(yc).astype(np.int64)
    fx, fy = (xc - x0).astype(np.float32), (yc - y0).astype(np.float32)
    out = []
    for im in imgs:
        a, b = im[y0, x0], im[y0, x0 + 1]
        c, d = im[y0 + 1, x0], im[y0 + 1, x0 + 1]
        out.append((a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy)
    return out, inside


def _references(obs: Observations) -> np.ndarray:
    """``[n]`` index of each observation's reference observation (its track's middle view)."""
    order = np.lexsort((obs.vi, obs.pj))
    counts = np.bincount(obs.pj, minlength=obs.n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ref_of_track = order[starts + counts // 2]
    return ref_of_track[obs.pj]


def _fit_chunk(T, tgt, ks, uv, grid, half, iters):
    """Gauss-Newton for observations ``ks`` (templates ``T [m, P]``); returns ``b [m, 2]``, ncc, A."""
    m = len(ks)
    A = np.tile(np.eye(2, dtype=np.float32), (m, 1, 1))
    b = uv[ks].astype(np.float32).copy()
    px, py = grid[:, 0], grid[:, 1]
    (I0, _, _), _ = tgt(b[:, :1] + px, b[:, 1:] + py)
    g, o = I0.std(1), I0.mean(1)                 # T is normalised: start from the target patch's statistics
    for _ in range(iters):
        x = b[:, :1] + A[:, 0, :1] * px + A[:, 0, 1:] * py
        y = b[:, 1:] + A[:, 1, :1] * px + A[:, 1, 1:] * py
        (I, gx, gy), ok = tgt(x, y)
        r = I - (g[:, None] * T + o[:, None])                                   # [m, P]
        J = np.stack([gx * px, gx * py, gy * px, gy * py, gx, gy, -T, -np.ones_like(T)], -1)  # [m, P, 8]
        JtJ = np.einsum("mpi,mpj->mij", J, J) + 1e-6 * np.eye(8, dtype=np.float32)
        step = -np.linalg.solve(JtJ, np.einsum("mpi,mp->mi", J, r)[..., None])[..., 0]
        A = A + step[:, :4].reshape(m, 2, 2)
        b = b + step[:, 4:6]
        g, o = g + step[:, 6], o + step[:, 7]
    x = b[:, :1] + A[:, 0, :1] * px + A[:, 0, 1:] * py
    y = b[:, 1:] + A[:, 1, :1] * px + A[:, 1, 1:] * py
    (I, _, _), ok = tgt(x, y)
    Ic, Tc = I - I.mean(1, keepdims=True), T - T.mean(1, keepdims=True)
    ncc = (Ic * Tc).sum(1) / np.maximum(np.sqrt((Ic ** 2).sum(1) * (Tc ** 2).sum(1)), 1e-12)
    ncc[~ok.all(1)] = -1.0
    return b.astype(np.float64), ncc, A


def refine_observations(images: list[np.ndarray], obs: Observations, forward: np.ndarray | None = None,
                        max_angle: float = 15.0, scale: float = 1.0, iters: int = 10, min_ncc: float = 0.8,
                        chunk: int = 4000) -> tuple[Observations, dict]:
    """Refined ``obs`` on ``images`` (float or integer ``[H, W]``, full resolution); module docstring.

    ``scale``: that of the copy the features came from (< 1: downscaled); the patch (15 pixels there), the
    band-pass and the largest accepted move (3 pixels there) are measured in its pixels, so a downscaled
    series is refined at full resolution on the detail its features saw.

    ``forward [V, 3]``: the views' (initial) viewing directions; observations seen more than ``max_angle``
    degrees away from their reference, and those whose fit failed, are dropped (a patch's appearance
    changes with the viewing direction: matches across wide angles were the least consistent). Returns the
    refined observations (tracks left with one view dropped) and a summary.
    """
    half, sigma, max_shift = round(7 / scale), 1.0 / scale, 3.0 / scale
    ref = _references(obs)
    keep = np.ones(len(obs), bool)
    if forward is not None:
        cos = np.einsum("ij,ij->i", forward[obs.vi], forward[obs.vi[ref]])
        keep &= cos >= np.cos(np.radians(max_angle))
    todo = np.nonzero((ref != np.arange(len(obs))) & keep)[0]
    ax = np.arange(-half, half + 1, dtype=np.float32)
    grid = np.stack(np.meshgrid(ax, ax, indexing="xy"), -1).reshape(-1, 2)        # [P, 2] (x, y) offsets
    prepare = lambda v: _smooth(images[v].astype(np.float32) / float(max(images[v].max(), 1)), sigma)
    # pass 1: templates, one reference view in memory at a time
    T = np.empty((len(todo), len(grid)), np.float32)
    for rv in np.unique(obs.vi[ref[todo]]):
        sel = np.nonzero(obs.vi[ref[todo]] == rv)[0]
        c = obs.uv[ref[todo[sel]]]
        T[sel] = _bilinear(prepare(rv), c[:, :1] + grid[:, 0], c[:, 1:] + grid[:, 1])[0][0]
    T = (T - T.mean(1, keepdims=True)) / np.maximum(T.std(1, keepdims=True), 1e-6)
    # pass 2: the fits, one target view in memory at a time
    uv, shift_all, n_ok = obs.uv.copy(), [], 0
    for v in np.unique(obs.vi[todo]):
        rows = np.nonzero(obs.vi[todo] == v)[0]
        target = prepare(v)
        tgt = lambda x, y, target=target: _bilinear(target, x, y)
        for s in range(0, len(rows), chunk):
            r = rows[s:s + chunk]
            ks = todo[r]
            b, ncc, A = _fit_chunk(T[r], tgt, ks, obs.uv, grid, half, iters)
            sv = np.linalg.svd(A, compute_uv=False)
            shift = np.linalg.norm(b - obs.uv[ks], axis=1)
            good = (shift < max_shift) & (ncc > min_ncc) & (sv[:, 1] > 0.5) & (sv[:, 0] < 2.0) & np.isfinite(b).all(1)
            uv[ks[good]] = b[good]
            keep[ks[~good]] = False
            n_ok += int(good.sum())
            shift_all.append(shift[good])
    shifts = np.concatenate(shift_all) if shift_all else np.zeros(0)
    info = {"refined": n_ok, "candidates": len(todo), "dropped": int((~keep).sum()), "fit_failed": len(todo) - n_ok,
            "beyond_angle": int((~keep).sum()) - (len(todo) - n_ok),
            "median_shift_px": float(np.median(shifts)) if len(shifts) else 0.0}
    return Observations(obs.vi, obs.pj, uv, obs.fi, obs.n_points).select(keep), info
