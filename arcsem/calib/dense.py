"""A denser start for training: many more points, from the calibrated cameras held fixed.

The adjustment needs only a few thousand well-spread tracks; training from them leaves parts of the views
empty (the substrate's debris, the borders) and its box too small. Two passes add points once the cameras are
known.

Surface fill (:func:`surface_fill`): in every fourth view, the depth of the adjustment's points that view
observes is interpolated over a pixel grid (linearly inside their hull, the nearest outside), and each grid
pixel inside their hull is lifted to 3-D at that depth. A lifted point is kept where the image agrees: its patch
must be textured (standard deviation >= ``min_std``) and, projected into the view's two partners
(:func:`partner_pairs`), correlate (NCC >= :data:`MIN_NCC`) with the patch there in at least one of them (a point
lifted across a depth edge lands on other texture and goes).

Dense keypoints (:func:`dense_points`): each view gets many more keypoints (:func:`~.features.detect_features`, ``dense_features`` per view), each view is matched to
its two partners nearest :data:`BEST_DEG` apart within ``[MIN_DEG, max_angle]`` (wide enough for depth, close
enough for SIFT), the matches become tracks (:func:`~.tracks.build_tracks`), and every track is triangulated
with the fixed cameras (:func:`~.geometry.triangulate`). Observations off by more than ``reject_px`` are
dropped twice (tracks left with one view go), and so are tracks whose views span less than :data:`MIN_DEG`
(too little parallax for their depth). Orthographic cameras only (the default model); a pinhole calibration
keeps its sparse points.
"""
from __future__ import annotations

import numpy as np

from .bundle import OrthoViews, residuals
from .features import Features, detect_features
from .geometry import project
from .matching import PairMatches, match_descriptors
from .tracks import Observations, build_tracks

__all__ = ["BEST_DEG", "MIN_DEG", "MIN_NCC", "dense_points", "partner_pairs", "surface_fill"]

MIN_DEG = 4.0   # the least angle between two views of a track (parallax for its depth)
BEST_DEG = 8.0  # the angle a view's partners are chosen nearest to
MIN_NCC = 0.5   # the correlation a textured patch of a lifted point must reach in a partner view
PATCH = 3       # patch half-size, pixels (7x7)


def partner_pairs(R: np.ndarray, max_deg: float, partners: int = 2) -> list[tuple[int, int]]:
    """Pairs ``(a, b)``, ``a < b``, of views ``R [V, 3, 3]`` (world -> camera): each view with its ``partners``
    views nearest :data:`BEST_DEG` apart among those ``MIN_DEG..max_deg`` apart (viewing directions)."""
    d = R[:, 2, :]
    ang = np.degrees(np.arccos(np.clip(d @ d.T, -1.0, 1.0)))
    out = set()
    for a in range(len(R)):
        ok = np.nonzero((ang[a] >= MIN_DEG) & (ang[a] <= max_deg))[0]
        for b in ok[np.argsort(np.abs(ang[a, ok] - BEST_DEG), kind="stable")][:partners]:
            out.add((min(a, int(b)), max(a, int(b))))
    return sorted(out)


def _span_deg(R: np.ndarray, obs: Observations) -> np.ndarray:
    """``[n_points]`` the largest angle between the viewing directions of two views of each track."""
    d = R[obs.vi, 2, :]
    span = np.zeros(obs.n_points)
    ref = np.zeros((obs.n_points, 3))
    ref[obs.pj] = d  # one of each track's directions (the last written)
    np.maximum.at(span, obs.pj, np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", d, ref[obs.pj]), -1, 1))))
    return span


def dense_points(pixels: list[np.ndarray], views: OrthoViews, n_features: int, scale: float, *, ratio: float = 0.8,
                 reject_px: float = 1.0, max_deg: float = 15.0, root: bool = True) -> tuple[np.ndarray, np.ndarray,
                                                                                            dict]:
    """Points ``[P, 3]`` (world frame of ``views``), their grey ``[P]`` in [0, 1] and statistics, from the views'
    images ``pixels`` (``[H, W]`` uint8/uint16, full resolution) with ``n_features`` keypoints each computed at
    ``scale`` (module docstring)."""
    feats: list[Features] = [detect_features(p, n_features, scale, root) for p in pixels]
    pairs = partner_pairs(views.R, max_deg)
    matches = []
    for a, b in pairs:
        ia, ib = match_descriptors(feats[a].desc, feats[b].desc, ratio)
        matches.append(PairMatches(a, b, ia, ib, np.zeros(4)))
    obs = build_tracks(matches, [f.xy for f in feats])
    n_tracks = obs.n_points
    for _ in range(2):
        if not len(obs):
            break
        obs = obs.select(residuals(views, views.triangulate(obs), obs) <= reject_px)
    if len(obs):
        wide = _span_deg(views.R, obs) >= MIN_DEG - 0.5
        obs = obs.select(wide[obs.pj])
    if not len(obs):
        return np.zeros((0, 3)), np.zeros(0, np.float32), {"pairs": len(pairs), "tracks": n_tracks, "points": 0}
    X = views.triangulate(obs)
    grey = np.concatenate([f.grey for f in feats])
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in feats])])
    g = np.bincount(obs.pj, grey[offsets[obs.vi] + obs.fi], obs.n_points) / np.maximum(obs.track_lengths(), 1)
    return X, g.astype(np.float32), {"pairs": len(pairs), "tracks": n_tracks, "points": len(X),
                                     "features_per_view": float(np.mean([len(f) for f in feats]))}


def _unit(pixels: np.ndarray) -> np.ndarray:
    return pixels.astype(np.float32) / (65535.0 if pixels.dtype == np.uint16 else 255.0)


def _patches(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``[n, (2 PATCH + 1)^2]`` bilinear patches of ``img [H, W]`` float32 centred at ``uv [n, 2]`` (pixel centres
    at +0.5)."""
    import cv2

    r = np.arange(-PATCH, PATCH + 1, dtype=np.float32)
    dx, dy = np.meshgrid(r, r)
    mx = (uv[:, None, 0] - 0.5 + dx.ravel()[None]).astype(np.float32)
    my = (uv[:, None, 1] - 0.5 + dy.ravel()[None]).astype(np.float32)
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    return (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1) + 1e-12)


def _lifted(views: OrthoViews, v: int, uv_obs: np.ndarray, z_obs: np.ndarray, size: tuple[int, int],
            stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The pixel grid of view ``v`` (every ``stride`` px, ``[n, 2]``) and its points ``[n, 3]`` at the depth
    interpolated from the observed points ``uv_obs [m, 2]`` at depths ``z_obs [m]``."""
    from scipy.interpolate import LinearNDInterpolator

    gx, gy = np.meshgrid(np.arange(stride / 2, size[0], stride), np.arange(stride / 2, size[1], stride))
    grid = np.stack([gx.ravel(), gy.ravel()], 1)
    z = LinearNDInterpolator(uv_obs, z_obs)(grid)
    grid, z = grid[np.isfinite(z)], z[np.isfinite(z)]  # inside the observed points' hull
    cam = np.concatenate([(grid - views.t[v]) / views.scale[v], z[:, None]], 1)
    return grid, cam @ views.R[v]


def surface_fill(pixels: list[np.ndarray], views: OrthoViews, X: np.ndarray, obs: Observations, *,
                 every: int = 4, cells: int = 96, max_deg: float = 15.0, min_std: float = 0.02
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Points ``[P, 3]`` and their grey ``[P]`` lifted from every ``every``-th view on a grid of about ``cells``
    columns, kept where a partner view agrees (module docstring); ``X [N, 3]``, ``obs``: the adjustment's points
    and observations."""
    h, w = pixels[0].shape[:2]
    stride = max(2, round(max(w, h) / cells))
    partners: dict[int, list[int]] = {}
    for a, b in partner_pairs(views.R, max_deg):
        partners.setdefault(a, []).append(b)
        partners.setdefault(b, []).append(a)
    imgs = [_unit(p) for p in pixels]
    pts, greys, tried = [], [], 0
    for v in range(0, len(views), every):
        mine = obs.vi == v
        if mine.sum() < 3 or not partners.get(v):
            continue
        uv_obs = views.project(X, obs)[mine]
        z_obs = (X[obs.pj[mine]] @ views.R[v].T)[:, 2]
        grid, P = _lifted(views, v, uv_obs, z_obs, (w, h), stride)
        tried += len(P)
        own = _patches(imgs[v], grid)
        best = np.full(len(P), -1.0)
        for b in partners[v]:
            uv_b = project(views.R, views.t, views.scale, P, np.full(len(P), b), np.arange(len(P)))
            inside = (uv_b >= PATCH).all(1) & (uv_b[:, 0] < w - PATCH) & (uv_b[:, 1] < h - PATCH)
            score = np.where(inside, _ncc(own, _patches(imgs[b], uv_b)), -1.0)
            best = np.maximum(best, score)
        keep = (best >= MIN_NCC) & (own.std(1) >= min_std)
        pts.append(P[keep])
        greys.append(own[keep, own.shape[1] // 2])
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, np.float32), {"lifted": 0, "kept": 0}
    P, g = np.concatenate(pts), np.concatenate(greys).astype(np.float32)
    return P, g, {"lifted": tried, "kept": len(P), "stride_px": stride}
