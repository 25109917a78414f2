"""Orthographic SEM cameras: stage angles to rotations, projection, and the linear solves under them.

A view ``i`` projects a world point ``X`` to pixels ``u = s_i P R_i X + t_i`` (``P`` keeps the camera's
``x, y``; ``R_i`` world -> camera rotation in OpenCV axes; ``s_i`` pixels per world unit; ``t_i`` the 2-D
image translation). Observations are flat arrays: ``vi [n]`` view index, ``pj [n]`` point index,
``uv [n, 2]`` pixels (centres at ``+0.5``, :mod:`arcsem.cameras`).

Stage model (eucentric): the stage frame has ``z`` along the stage normal (towards the gun at zero tilt),
``x`` along the tilt axis. A view at stage rotation ``r`` (about the normal) and tilt ``t`` (about the
chamber's tilt axis, which appears at angle ``axis`` from the image ``x`` axis) has
``R = Rz_cam(axis) . diag(1, -1, -1) . Rx(t) . Rz(r)``: at zero tilt the camera looks down the normal with
the stage ``x`` to the right and ``y`` up in the image.
"""
from __future__ import annotations

import numpy as np

__all__ = ["left_jacobian", "project", "rodrigues", "rot_x", "rot_z", "skew", "solve_points_translations",
           "stage_rotation", "triangulate"]


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def stage_rotation(tilt_deg: float, rot_deg: float = 0.0, axis_deg: float = 0.0) -> np.ndarray:
    """World (stage) -> camera rotation ``[3, 3]`` of a view at these stage angles (module docstring)."""
    return rot_z(np.radians(axis_deg)) @ np.diag([1.0, -1.0, -1.0]) @ rot_x(np.radians(tilt_deg)) @ rot_z(
        np.radians(rot_deg))


def skew(v: np.ndarray) -> np.ndarray:
    """``[..., 3]`` -> cross-product matrices ``[..., 3, 3]``."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation vectors ``[N, 3]`` -> rotation matrices ``[N, 3, 3]`` (``exp([w]x)``)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = theta < 1e-8
    a = np.where(small, 1.0, np.sin(theta) / np.where(small, 1.0, theta))
    b = np.where(small, 0.5, (1 - np.cos(theta)) / np.where(small, 1.0, theta ** 2))
    return np.eye(3) + a * K + b * (K @ K)


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` left Jacobian of SO(3): ``d exp([w]) v / dw = -[exp([w]) v]x J_l(w)``."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t ** 3)
    return np.eye(3) + a * K + b * (K @ K)


def project(R: np.ndarray, t: np.ndarray, scale: np.ndarray, X: np.ndarray, vi: np.ndarray,
            pj: np.ndarray) -> np.ndarray:
    """Pixels ``[n, 2]`` of points ``X [N, 3]`` seen by views ``R [V, 3, 3]``, ``t [V, 2]``, ``scale [V]``."""
    cam = np.einsum("nij,nj->ni", R[vi, :2, :], X[pj])
    return scale[vi, None] * cam + t[vi]


def _point_normals(G: np.ndarray, pj: np.ndarray, n_points: int, ridge: float) -> np.ndarray:
    """``[N, 3, 3]`` per-point normal matrices ``sum G^T G`` (+ ``ridge I``) of observation Jacobians ``G [n, 2, 3]``."""
    A = np.zeros((n_points, 3, 3))
    np.add.at(A, pj, np.einsum("nki,nkj->nij", G, G))
    return A + ridge * np.eye(3)


def solve_points_translations(R: np.ndarray, scale: np.ndarray, vi: np.ndarray, pj: np.ndarray, uv: np.ndarray,
                              n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares points ``X [N, 3]`` and translations ``t [V, 2]`` for fixed rotations and scales.

    The problem ``min sum |s P R_i X_j + t_i - u|^2`` is linear; the points are eliminated (Schur
    complement on their 3 x 3 blocks), the ``2V x 2V`` system in the translations is solved by least squares
    (its 3-D translation gauge: minimum norm), then each point is solved given the translations, and the
    points are re-centred on their mean (the translations follow). Each view must be the view of at most
    one observation per point.
    """
    V = len(R)
    G = scale[vi, None, None] * R[vi, :2, :]                       # [n, 2, 3] d uv / d X
    A_inv = np.linalg.inv(_point_normals(G, pj, n_points, 1e-9))  # [N, 3, 3]
    b = np.zeros((n_points, 3))
    np.add.at(b, pj, np.einsum("nki,nk->ni", G, uv))
    # pairs (k, k') of observations of the same point: S -= G_k A^-1 G_k'^T, rhs -= G_k A^-1 b_j
    order = np.argsort(pj, kind="stable")
    counts = np.bincount(pj, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k1, k2 = _pairs(order, counts, starts)
    M = np.einsum("nij,njk->nik", G[k1], A_inv[pj[k1]])            # [pairs, 2, 3]
    blocks = np.einsum("nik,nlk->nil", M, G[k2])                   # [pairs, 2, 2]
    S = np.zeros((V, 2, V, 2))
    np.add.at(S, (vi[k1], slice(None), vi[k2]), -blocks)
    n_per_view = np.bincount(vi, minlength=V)
    S[np.arange(V), :, np.arange(V), :] += n_per_view[:, None, None] * np.eye(2)
    rhs = np.zeros((V, 2))
    np.add.at(rhs, vi, uv - np.einsum("nik,nk->ni", G, np.einsum("nij,nj->ni", A_inv[pj], b[pj])))
    t = np.linalg.lstsq(S.reshape(2 * V, 2 * V), rhs.reshape(-1), rcond=1e-10)[0].reshape(V, 2)
    X = triangulate(R, t, scale, vi, pj, uv, n_points)
    mean = X.mean(0)
    return X - mean, t + scale[:, None] * (R[:, :2, :] @ mean)


def _pairs(order: np.ndarray, counts: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every ordered pair ``(k, k')`` of observations of the same point (``k = k'`` included)."""
    per = counts[counts > 0]
    st = starts[counts > 0]
    rep = np.repeat(np.arange(len(per)), per * per)                # pair -> point group
    offs = np.arange(len(rep)) - np.repeat(np.cumsum(per * per) - per * per, per * per)
    a, c = offs // per[rep], offs % per[rep]
    return order[st[rep] + a], order[st[rep] + c]


def triangulate(R: np.ndarray, t: np.ndarray, scale: np.ndarray, vi: np.ndarray, pj: np.ndarray, uv: np.ndarray,
                n_points: int) -> np.ndarray:
    """Least-squares points ``[N, 3]`` for fixed cameras (points with < 2 views get a tiny ridge, stay finite)."""
    G = scale[vi, None, None] * R[vi, :2, :]
    A = _point_normals(G, pj, n_points, 1e-9)
    b = np.zeros((n_points, 3))
    np.add.at(b, pj, np.einsum("nki,nk->ni", G, uv - t[vi]))
    return np.linalg.solve(A, b[..., None])[..., 0]
