"""The world frame of a calibrated series: specimen at the origin, substrate behind it, tilt axis along x.

* **Substrate**: the plane through the most sparse points (RANSAC, inliers within 1 % of the points'
  extent, then within three robust sigmas of the inliers' own distances) when it holds >= 8 % of them (and
  30), faces the cameras (normal within 80 degrees of their mean backward direction; for stage-initialised
  series within 45 degrees of the stage normal), bounds the rest (>= 80 % of the other points on one side:
  a plane through the middle of a specimen has points on both sides) and is at least as wide as they are
  (a flat cap of the specimen is narrower than the specimen). Points off the plane are the specimen.
* **Depth reversal**: parallel projection cannot tell a relief from its mirror image (``X -> -X``,
  ``R -> diag(-1, -1, 1) R`` reproduce every pixel). Series calibrated from stage angles take the depth
  direction of arcsem's tilt convention (:mod:`.init`; a substrate in front of the specimen is reported as a
  warning); factorised series take the mirror in which the specimen stands in front of its substrate (none
  found: as factorised). ``flip`` takes the other one.
* **Axes**: ``z`` along the stage normal for stage-initialised series, else along the substrate normal
  towards the cameras (without a substrate: the cameras' mean backward direction); ``x`` along the principal tilt
  axis (:func:`tilt_axes`) made orthogonal to ``z``; origin at the centre of the specimen points' box
  (their 2nd to 98th percentiles; :func:`specimen_points`: above the substrate, debris left out).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from .bundle import OrthoViews

__all__ = ["DEBRIS_SHARE", "LINK", "Frame", "above_substrate", "apply_frame", "find_substrate", "mirror", "refit_substrate",
           "specimen_points", "split_debris", "tilt_axes", "world_frame"]


@dataclass
class Frame:
    """``rotation [3, 3]`` (old world -> new world), ``centre [3]`` (old coordinates of the new origin),
    ``substrate`` ``[N]`` bool or None, ``mirrored``: the depth reversal was applied, ``notes``; ``height [N]``:
    each point's signed distance from the substrate plane (positive on the cameras' side; None without one)."""

    rotation: np.ndarray
    centre: np.ndarray
    substrate: np.ndarray | None
    mirrored: bool
    notes: list[str]
    height: np.ndarray | None = None


def above_substrate(substrate: np.ndarray | None, height: np.ndarray | None, n_points: int) -> np.ndarray:
    """``[N]`` bool: the points clearly above the substrate (more than three times the plane's tolerance, the
    largest distance of its inliers); every point without a substrate, or when fewer than 10 are that high.
    Points just off the plane (its scatter, points on a tilted edge of the substrate) are not the specimen:
    counted in, they stretched the specimen's box several times (and with it the Gaussians' length scale)."""
    if substrate is None or height is None:
        return np.ones(n_points, bool)
    tol = float(np.abs(height[substrate]).max()) if substrate.any() else 0.0
    spec = height > 3.0 * tol
    return spec if spec.sum() >= 10 else np.ones(n_points, bool)


DEBRIS_SHARE = 0.2  # a part with fewer points than this share of the largest one's is debris (set by hand)
LINK = 4.0  # two points are neighbours within LINK x the median distance of a point to its nearest one


def split_debris(X: np.ndarray) -> np.ndarray:
    """``[n]`` bool, True for the specimen: of the points ``X [n, 3]`` above the substrate, those in the connected
    parts of their neighbour graph (points within :data:`LINK` times the median nearest-neighbour distance) that
    hold at least :data:`DEBRIS_SHARE` as many points as the largest part; the rest are debris. All True for
    fewer than 10 points."""
    if len(X) < 10:
        return np.ones(len(X), bool)
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    tree = cKDTree(X)
    nn = tree.query(X, k=2)[0][:, 1]
    pairs = tree.query_pairs(LINK * float(np.median(nn)), output_type="ndarray")
    from scipy.sparse import coo_matrix

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(X), len(X)))
    _n, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    return sizes[labels] >= DEBRIS_SHARE * sizes.max()


def specimen_points(substrate: np.ndarray | None, height: np.ndarray | None, X: np.ndarray) -> np.ndarray:
    """``[N]`` bool: the specimen's points of ``X [N, 3]``: those above the substrate (:func:`above_substrate`) less
    the debris (:func:`split_debris`); without a substrate, every point. The frame's origin, the dataset's
    ``aabb`` and the masks' seeds all take these: debris far out on the substrate, counted in, made the built-in
    scene's specimen box six times the grain and put its origin off the grain (``aabb`` scales the Gaussians'
    learning rates and split threshold)."""
    above = above_substrate(substrate, height, len(X))
    if substrate is None or height is None:
        return above
    idx = np.flatnonzero(above)
    out = np.zeros(len(X), bool)
    out[idx] = split_debris(X[idx])
    return out


def find_substrate(X: np.ndarray, towards: np.ndarray, max_angle: float = 60.0, iters: int = 400, seed: int = 0
                   ) -> tuple[np.ndarray, float, np.ndarray] | None:
    """``(normal [3] towards the cameras, offset, inliers [N])`` of the substrate plane, or None; its normal
    must lie within ``max_angle`` degrees of ``towards``."""
    if len(X) < 30:
        return None
    lo, hi = np.percentile(X, 2, axis=0), np.percentile(X, 98, axis=0)
    thr = 0.01 * float(np.linalg.norm(hi - lo))
    rng = np.random.default_rng(seed)
    tri = X[rng.integers(0, len(X), size=(iters, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ok = np.linalg.norm(n, axis=1) > 1e-12
    n = n[ok] / np.linalg.norm(n[ok], axis=1, keepdims=True)
    d = np.einsum("ik,ik->i", n, tri[ok, 0])
    inl = np.abs(X @ n.T - d) < thr                                     # [N, I]
    best = int(inl.sum(0).argmax())
    mask = inl[:, best]
    if mask.sum() < max(30, 0.08 * len(X)):
        return None
    floor = 1e-3 * thr  # an exact plane has no scatter: the tolerance must not vanish
    for _ in range(2):  # refit; then tighten the tolerance to the inliers' own scatter (3 robust sigmas)
        c = X[mask].mean(0)
        normal = np.linalg.svd(X[mask] - c, full_matrices=False)[2][-1]
        dist = np.abs((X - c) @ normal)
        thr = min(thr, max(3 * 1.4826 * float(np.median(dist[mask])), floor))
        mask = dist < thr
    normal = normal if normal @ towards >= 0 else -normal
    if normal @ towards < np.cos(np.radians(max_angle)):
        return None
    side = (X - c) @ normal
    mask = np.abs(side) < thr
    above = float(np.mean(side[~mask] > 0)) if (~mask).any() else 1.0
    if max(above, 1 - above) < 0.8 or _span(X[mask], normal) < _span(X[~mask], normal):
        return None  # a plane with points on both sides, or a cap of the specimen narrower than the specimen
    return normal, float(normal @ c), mask


def _span(P: np.ndarray, normal: np.ndarray) -> float:
    """Extent of points ``P [k, 3]`` along the plane of ``normal``: the longer 5-95 % span of two in-plane axes."""
    if len(P) < 5:
        return 0.0
    a = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    q = np.percentile(P @ np.stack([a, b], 1), [5, 95], axis=0)
    return float((q[1] - q[0]).max())


def mirror(views: OrthoViews, X: np.ndarray) -> tuple[OrthoViews, np.ndarray]:
    """The depth reversal of parallel projection: same pixels, mirrored relief."""
    return replace(views, R=np.diag([-1.0, -1.0, 1.0]) @ views.R), -X


def tilt_axes(views: OrthoViews, order: list[int] | None = None, min_deg: float = 0.5) -> list[dict]:
    """Rotation axes between consecutive views (file order), grouped when within 20 degrees of each other.

    Each group: ``{"axis": world unit vector, "image_angle_deg": the axis' direction in the first view of the
    group (from the image x axis, towards y), "out_of_plane_deg": its angle out of that image plane,
    "pairs": pairs in the group, "mean_step_deg": their mean rotation angle}``.
    """
    order = list(range(len(views))) if order is None else order
    groups: list[dict] = []
    for i, j in itertools.pairwise(order):
        Rrel = views.R[j] @ views.R[i].T
        angle = np.degrees(np.arccos(np.clip((np.trace(Rrel) - 1) / 2, -1, 1)))
        if angle < min_deg:
            continue
        w = np.array([Rrel[2, 1] - Rrel[1, 2], Rrel[0, 2] - Rrel[2, 0], Rrel[1, 0] - Rrel[0, 1]])
        axis = views.R[i].T @ (w / max(np.linalg.norm(w), 1e-12))     # camera i -> world
        for g in groups:
            if abs(g["axis"] @ axis) > np.cos(np.radians(20)):
                g["sum"] += angle * (axis if g["axis"] @ axis > 0 else -axis)
                g["pairs"] += 1
                g["angles"].append(angle)
                break
        else:
            groups.append({"axis": axis, "sum": angle * axis, "pairs": 1, "angles": [angle], "first": i})
    out = []
    for g in sorted(groups, key=lambda g: -g["pairs"]):
        a = g["sum"] / np.linalg.norm(g["sum"])
        cam = views.R[g["first"]] @ a
        out.append({"axis": a.tolist(), "image_angle_deg": float(np.degrees(np.arctan2(cam[1], cam[0]))),
                    "out_of_plane_deg": float(np.degrees(np.arcsin(np.clip(cam[2], -1, 1)))),
                    "pairs": g["pairs"], "mean_step_deg": float(np.mean(g["angles"]))})
    return out


def _depth_direction(views: OrthoViews, X: np.ndarray, back: np.ndarray, stage_frame: bool, flip: bool):
    """The mirror to keep (module docstring): ``(views, X, substrate plane or None, mirrored, notes)``."""
    plane = find_substrate(X, np.array([0.0, 0.0, 1.0]), 45.0) if stage_frame else find_substrate(X, back, 80.0)
    behind = None
    if plane is not None and (~plane[2]).any():
        behind = bool(np.median(X[~plane[2]] @ plane[0] - plane[1]) >= 0)  # specimen on the cameras' side
    if stage_frame:
        notes = ["depth direction from the stage angles (arcsem's tilt convention" + (", flipped)" if flip else ")")]
        if behind is False:
            notes.append("warning: the specimen points lie behind the best substrate plane; if the relief looks "
                         "inverted, run again with --flip-depth")
        return views, X, plane, False, notes
    mirrored = (behind is False) != flip
    notes = ["depth direction from the substrate: the specimen stands in front of it" if behind is not None else
             "no substrate plane found: the depth direction of the factorisation is arbitrary (--flip-depth takes "
             "the other one)"]
    if mirrored:
        views, X = mirror(views, X)
        plane = find_substrate(X, back, 80.0)
    return views, X, plane, mirrored, notes


def world_frame(views: OrthoViews, X: np.ndarray, stage_frame: bool, flip: bool = False
                ) -> tuple[OrthoViews, np.ndarray, Frame]:
    """Choose axes and origin, and the depth direction of factorised series (module docstring); returns the
    moved views and points. ``stage_frame``: the views came from stage angles (their frame is the stage's);
    ``flip``: take the mirrored relief."""
    back = -views.R[:, 2, :].mean(0)
    back /= np.linalg.norm(back)
    views, X, plane, mirrored, notes = _depth_direction(views, X, back, stage_frame, flip)
    sub = None if plane is None else plane[2]
    if plane is not None:
        notes.append(f"substrate plane through {int(sub.sum())} of {len(X)} points")
    z = np.array([0.0, 0.0, 1.0]) if stage_frame else (plane[0] if plane is not None else back)
    axes = tilt_axes(views)
    x = np.array(axes[0]["axis"]) if axes else views.R[0, 0]
    x = x - (x @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = views.R[0, 0] - (views.R[0, 0] @ z) * z
    x /= np.linalg.norm(x)
    rot = np.stack([x, np.cross(z, x), z])
    height = None if plane is None else X @ plane[0] - plane[1]
    local = X[specimen_points(sub, height, X)] @ rot.T
    centre = rot.T @ (0.5 * (np.percentile(local, 2, axis=0) + np.percentile(local, 98, axis=0)))
    frame = Frame(rot, centre, sub, mirrored, notes, height)
    views, X = apply_frame(views, X, frame)
    return views, X, frame


def apply_frame(views: OrthoViews, X: np.ndarray, frame: Frame) -> tuple[OrthoViews, np.ndarray]:
    """Views and points in the new frame: ``X' = rot (X - centre)``, ``R' = R rot^T``, ``t`` follows."""
    t = views.t + views.scale[:, None] * np.einsum("vij,j->vi", views.R[:, :2, :], frame.centre)
    return replace(views, R=views.R @ frame.rotation.T, t=t), (X - frame.centre) @ frame.rotation.T



def refit_substrate(views, X: np.ndarray, frame: Frame, stage_frame: bool) -> Frame:
    """``frame`` with the substrate found again among new points ``X [N, 3]`` (already in its world frame; e.g.
    after the perspective refinement, whose points differ): same rules as :func:`world_frame`."""
    back = -views.R[:, 2, :].mean(0)
    back /= np.linalg.norm(back)
    plane = find_substrate(X, np.array([0.0, 0.0, 1.0]), 45.0) if stage_frame else find_substrate(X, back, 80.0)
    notes = [n for n in frame.notes if not n.startswith("substrate plane through")]
    if plane is None:
        return replace(frame, substrate=None, height=None, notes=notes)
    notes.append(f"substrate plane through {int(plane[2].sum())} of {len(X)} points")
    return replace(frame, substrate=plane[2], height=X @ plane[0] - plane[1], notes=notes)
