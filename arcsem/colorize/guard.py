"""Guarded correspondences for TCM and CCM: a match is kept only where the evidence for it is confident.

The paper's TCM (after Ref-NPR) pairs every feature location of a view with its nearest reference feature by cosine
distance, and CCM every cell; on a scene whose parts look alike in grey, such matches carry colours between parts.
Here a location's match is searched among the reference locations that are **geometrically compatible** with it
(stage-1 geometry: the surface normal's elevation towards the cameras and the height above the specimen's lowest
point, :func:`geometry_descriptors`), and kept only if it passes:

* the **ratio test** (Lowe 2004): its cosine distance is below ``ratio`` times that of the best compatible
  location that is not its neighbour (more than ``exclude`` cells away in the same reference, or in another one),
  so a match that could as well be elsewhere is dropped;
* **mutual nearest neighbours**: the matched reference location's own nearest compatible location in the view is
  within ``exclude`` cells of the query;
* **agreement across views** (:func:`cross_view_agreement`): the colour a match brings to a surface point must
  agree (within ``views_tol``) with the median of what the other views' matches bring to the same point.

Where no location passes, the view location gets no target and the losses pull nothing there. And with
``uncovered_only`` (the default) the matches act only on the cells the pseudo-colour target leaves
(:func:`uncovered_cells`): where the stage-1 geometry already says which reference pixel a point shows, an
appearance match is the weaker evidence. Last, :func:`match_check` asks whether the kept matches carry colour at
all, where the geometry can tell (the covered cells): a loss whose matches do no better than the guess made without
them there (the grey prior, or the references' mean colour) is dropped. There the search is made as for a point no
reference sees: away from the location's own surface point, which the reference shows on a covered cell (found
there, a match says nothing of the points the losses act on; measured on the built-in scenes with one reference,
the matches were closer than the prior to the pseudo-colours on the covered cells and 2-5 dB further from the truth
outside the coverage, `benchmarks/match_outside.py`).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..cameras import Cameras
from ..configs import GuardConfig

__all__ = ["GuardConfig", "cross_view_agreement", "geometry_descriptors", "grid_positions", "guarded_nearest",
           "match_check", "uncovered_cells"]


def uncovered_cells(valid: Tensor, shape: tuple[int, int]) -> Tensor:
    """``[N, h, w]`` bool: the cells of an ``h x w`` grid over each view where under half the pixels have a
    pseudo-colour (``valid [N, H, W]``; area-weighted, so a grid need not divide the image)."""
    share = F.interpolate(valid[:, None].float(), size=tuple(shape), mode="area")[:, 0]
    return share < 0.5


def geometry_descriptors(cams: Cameras, depths: Tensor, normals: Tensor) -> Tensor:
    """``[N, 2, H, W]`` per pixel: the normal's elevation ``n . u`` and the height ``(x - x_low) . u / extent``, with
    ``u`` the direction towards the cameras (minus their mean viewing direction: SEM views look down on the stage)
    and ``x_low``/``extent`` the 1st percentile and the 1st-99th percentile span of the heights of all surface pixels.
    NaN where a pixel has no depth (``depths [N, H, W]``, <= 0: none; world ``normals [N, H, W, 3]``)."""
    up = -F.normalize(cams.forward.double().mean(0), dim=0)
    pts = cams.to(dtype=torch.float64).unproject(depths.double())
    h = (pts @ up).float()
    ok = depths > 0
    if not bool(ok.any()):
        return torch.full((len(depths), 2, *depths.shape[1:]), float("nan"))
    lo, hi = torch.quantile(h[ok][:: max(1, int(ok.sum()) // 200_000)], torch.tensor([0.01, 0.99]))
    height = (h - lo) / (hi - lo).clamp_min(1e-9)
    elev = (normals.double() @ up).float()
    out = torch.stack([elev, height], 1)
    return torch.where(ok[:, None], out, torch.full_like(out, float("nan")))


def grid_positions(R: int, h: int, w: int) -> Tensor:
    """``[R*h*w, 3]`` (reference, row, column) of flattened reference-major grid locations."""
    r, y, x = torch.meshgrid(torch.arange(R), torch.arange(h), torch.arange(w), indexing="ij")
    return torch.stack([r, y, x], -1).reshape(-1, 3)


def _compatible(qg: Tensor, kg: Tensor, tol: Tensor) -> Tensor:
    """``[Q, K]`` bool: every descriptor within ``tol [G]`` (NaN: never)."""
    return ((qg[:, None, :] - kg[None, :, :]).abs() <= tol).all(-1)


def guarded_nearest(query: Tensor, keys: Tensor, query_geo: Tensor, key_geo: Tensor, query_pos: Tensor,
                    key_pos: Tensor, cfg: GuardConfig, chunk: int = 1024,
                    apart: tuple[Tensor, Tensor, float] | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Nearest compatible key by cosine distance, with the ratio and mutual tests.

    Args: query ``[Q, D]`` features of one view's locations, keys ``[K, D]`` of the references'; query_geo ``[Q, G]``,
        key_geo ``[K, G]`` geometry descriptors (NaN: unknown, never compatible); query_pos ``[Q, 2]`` (row, col),
        key_pos ``[K, 3]`` (reference, row, col) grid positions; apart: ``(query points [Q, 3], key points [K, 3],
        radius)``: keys within ``radius`` of the query's own surface point are not compatible (the search a point
        no reference sees gets: :func:`match_check`).
    Returns: index ``[Q]`` into the keys, cosine distance ``[Q]`` and kept ``[Q]`` bool.
    """
    tol = torch.tensor([cfg.normal_tol, cfg.height_tol])[: query_geo.shape[1]]
    kn, qn_all = F.normalize(keys.float(), dim=-1, eps=1e-8), F.normalize(query.float(), dim=-1, eps=1e-8)
    Q, K = len(query), len(keys)
    idx, dist, ratio_ok = torch.zeros(Q, dtype=torch.long), torch.full((Q,), 2.0), torch.zeros(Q, dtype=torch.bool)
    col_best, col_arg = torch.full((K,), -2.0), torch.zeros(K, dtype=torch.long)
    kp = key_pos.float()
    for s in range(0, Q, chunk):
        sim = qn_all[s:s + chunk] @ kn.T
        ok = _compatible(query_geo[s:s + chunk], key_geo, tol)
        if apart is not None:  # NaN points (no surface) have NaN geometry: incompatible already
            ok &= ~(torch.cdist(apart[0][s:s + chunk].float(), apart[1].float()) <= apart[2])
        sim = torch.where(ok, sim, torch.full_like(sim, -2.0))
        best, arg = sim.max(1)
        far = ((kp[None, :, 0] != kp[arg][:, None, 0])
               | ((kp[None, :, 1:] - kp[arg][:, None, 1:]).abs().amax(-1) > cfg.exclude))
        second = torch.where(far, sim, torch.full_like(sim, -2.0)).max(1).values
        idx[s:s + chunk], dist[s:s + chunk] = arg, 1.0 - best
        ratio_ok[s:s + chunk] = (best > -2.0) & ((1.0 - best) <= cfg.ratio * (1.0 - second))
        cb, ca = sim.max(0)
        upd = cb > col_best
        col_best, col_arg = torch.where(upd, cb, col_best), torch.where(upd, ca + s, col_arg)
    back = query_pos[col_arg[idx]].float()
    mutual = (back - query_pos.float()).abs().amax(-1) <= cfg.exclude
    return idx, dist, ratio_ok & (mutual | (not cfg.mutual))


def cross_view_agreement(points: list[Tensor], colours: list[Tensor], keep: list[Tensor], cell: float,
                         tol: float) -> list[Tensor]:
    """Which kept matches agree with the other views about the colour of their surface point.

    Args: per view, its locations' world points ``[L, 3]`` (NaN: no surface), the colour each match brings
        ``[L, 3]`` and whether the match is kept ``[L]``; cell: the world size of a location (points in one cube
        of that size are one surface point); tol: the largest channel difference from the point's median colour.
    Returns: per view ``[L]`` bool: kept, and either the only view with a kept match at that point or within
        ``tol`` of the median over every view's kept matches there.
    """
    import numpy as np
    import pandas as pd

    out = [k.clone() & torch.isfinite(p).all(-1) for k, p in zip(keep, points)]
    sel = [torch.nonzero(o)[:, 0] for o in out]
    if not sum(len(x) for x in sel):
        return out
    view = np.concatenate([np.full(len(x), v) for v, x in enumerate(sel)])
    idx = torch.cat(sel).numpy()
    pts = torch.cat([p[x].double() for p, x in zip(points, sel)]).numpy()
    col = torch.cat([c[x].float() for c, x in zip(colours, sel)]).numpy()
    _, group = np.unique(np.floor(pts / cell).astype(np.int64), axis=0, return_inverse=True)
    df = pd.DataFrame({"g": group.reshape(-1), "v": view, "r": col[:, 0], "gr": col[:, 1], "b": col[:, 2]})
    views = df.groupby("g")["v"].nunique()
    med = df.groupby("g")[["r", "gr", "b"]].median()
    off = np.abs(col - med.loc[df["g"]].to_numpy()).max(1) > tol
    bad = off & (views.loc[df["g"]].to_numpy() >= 2)
    for v in np.unique(view[bad]):
        out[int(v)][torch.from_numpy(idx[bad & (view == v)])] = False
    return out


def _cell_means(x: Tensor, valid: Tensor, grid: tuple[int, int]) -> Tensor:
    """``[N, h*w, 3]``: the mean of ``x [N, H, W, 3]`` over the ``valid [N, H, W]`` pixels of each cell of ``grid``."""
    area = F.interpolate(valid[:, None].float(), size=grid, mode="area")[:, 0].clamp_min(1e-6)[..., None]
    sums = F.interpolate((x * valid[..., None]).permute(0, 3, 1, 2).float(), size=grid, mode="area")
    return (sums.permute(0, 2, 3, 1) / area).reshape(len(valid), -1, 3)


def match_check(guidance, views: list[int], pseudo: Tensor, valid: Tensor, guess: Tensor,
                apart: tuple[Tensor, float, float] | None = None) -> dict[str, dict]:
    """Do the kept matches carry colour? Checked where the geometry answers: on the cells of the non-reference
    ``views`` that the 2-D pseudo-colours cover (``valid [N, H, W]``, at least half the cell), the colour each kept
    match brings (:meth:`~arcsem.colorize.guidance.Guidance.carried`) against the cell's mean pseudo-colour
    (``pseudo [N, H, W, 3]``), and the same for the guess made without matches (``guess``: ``[3]``, the references'
    mean colour, or ``[N, H, W, 3]``, a colour per pixel: the grey prior, :mod:`arcsem.colorize.prior`; its cell
    mean over the same pixels). A loss whose matches are no closer than the guess is dropped (``keep`` false); with
    one reference this is the only evidence for TCM and CCM there is. ``apart``: ``(points [N, H, W, 3], pixel
    footprint, factor)``: the matches searched more than ``factor`` cells from each location's own surface point
    (:meth:`~arcsem.colorize.guidance.Guidance.apart_matches`) instead of the guidance's own. Returns ``{"tcm":
    {...}, "ccm": {...}}``: mean squared errors ``match``, ``guess``, the ``cells`` compared and ``keep``; the TCM
    blocks are pooled."""
    found = {v: guidance.apart_matches(v, *apart) for v in views} if apart is not None else {}
    sums = {"tcm": [0.0, 0.0, 0], "ccm": [0.0, 0.0, 0]}
    guess = guess.float().expand_as(pseudo) if guess.dim() == 1 else guess.float()
    for name, grid in guidance.kinds():
        cover = ~uncovered_cells(valid, grid)
        mean, base = _cell_means(pseudo, valid, grid), _cell_means(guess, valid, grid)
        acc = sums["ccm" if name == "ccm" else "tcm"]
        for v in views:
            cols, keep = guidance.carried(v, name, found.get(v))
            sel = keep & cover[v].reshape(-1)
            acc[0] += float(((cols[sel].float() - mean[v][sel]) ** 2).sum())
            acc[1] += float(((base[v][sel] - mean[v][sel]) ** 2).sum())
            acc[2] += int(sel.sum())
    return {k: {"match": m / max(3 * n, 1), "guess": f / max(3 * n, 1), "cells": n, "keep": n > 0 and m < f}
            for k, (m, f, n) in sums.items()}
