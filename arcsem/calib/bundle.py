"""Robust bundle adjustment of orthographic SEM views (``scipy.optimize.least_squares``, sparse Jacobian).

The points are not unknowns of the optimiser: under parallel projection they are a linear least-squares
solution for given views (:func:`~.geometry.triangulate`), so the residuals ``s_i P R_i X_j(views) + t_i - u``
are a function of the views alone (variable projection; Golub & Pereyra 1973, for bundle adjustment Hong
et al., CVPR 2017). Its Jacobian is the views' Jacobian projected off each point's three columns (Kaufman's
form) ``J_k - G_k A_j^-1 sum_{k' in j} G_k'^T J_k'``, with ``G`` the observations' point Jacobians and
``A_j = sum G^T G``: sparse (a row touches the views of its track) and analytic. Eliminating the points
removes the depth directions of thousands of short tracks from the trust-region steps.

Two rotation models (:class:`StageModel`):

* **stage** (stage angles known): ``R_i = exp([q]x) Q . diag(1, -1, -1) . Rx(T_i + dT_i) . Rz(S_i + dS_i)``
  (:func:`~.geometry.stage_rotation`): one camera-frame rotation ``q`` shared by all views (where the tilt
  axis lies in the image, beam misalignment) and per view small corrections of its tilt ``dT_i`` and stage
  rotation ``dS_i``, each with a prior residual ``sqrt(n_i) d / sigma`` (``n_i`` observations in view ``i``:
  a correction of ``sigma`` costs as much as a one-pixel error on every observation of the view). Parallel
  projection leaves the angular steps along one arc weakly determined by the images (a depth-scale / angle
  trade, the bas-relief ambiguity of short tracks), and the appearance of an SEM surface changes with the
  viewing direction, which biases feature positions by tenths of a pixel: the stage readout pins the steps,
  the images fit where the tilt axis lies, the beam's misalignment and the translations.
* **free**: a rotation increment ``w_i`` per view (``R_i = exp([w_i]x) R_i^0``), view ``fixed`` held (the
  rotation gauge). For factorised series without stage angles.

Per view also the image translation ``t_i`` and, with ``per_view_scale``, ``log m_i`` (magnification drift,
``s_i = s m_i``; view ``fixed`` held). The translation gauge (the points' 3-D translation) is removed by
holding ``t_fixed`` and one coordinate of another view's translation. The shared scale ``s`` (pixels per
world unit) is not estimated: under parallel projection it trades exactly against the size of the scene.
A robust loss (Huber by default, ``f_scale`` pixels) acts on all residuals.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .geometry import _pairs, left_jacobian, project, rodrigues, rot_x, rot_z, skew, triangulate
from .tracks import Observations

__all__ = ["OrthoViews", "StageModel", "bundle_adjust", "eliminated_jacobian", "local_values", "residuals"]

_C0 = np.diag([1.0, -1.0, -1.0])


@dataclass
class OrthoViews:
    """``V`` orthographic views: ``R [V, 3, 3]`` world -> camera, ``t [V, 2]`` pixels, ``scale [V]`` pixels
    per world unit."""

    R: np.ndarray
    t: np.ndarray
    scale: np.ndarray

    def __len__(self) -> int:
        return len(self.R)

    def project(self, X: np.ndarray, obs: Observations) -> np.ndarray:
        """``[n, 2]`` pixels of the points ``X [N, 3]`` at the observations."""
        return project(self.R, self.t, self.scale, X, obs.vi, obs.pj)

    def triangulate(self, obs: Observations) -> np.ndarray:
        """``[N, 3]`` least-squares points of ``obs`` for these views."""
        return triangulate(self.R, self.t, self.scale, obs.vi, obs.pj, obs.uv, obs.n_points)


@dataclass
class StageModel:
    """Signed stage angles in degrees (``tilt [V]``, ``rotation [V]``: the convention's signs applied), the
    camera-frame rotation ``Q [3, 3]`` and the prior ``sigma_deg`` of the per-view corrections."""

    tilt: np.ndarray
    rotation: np.ndarray
    Q: np.ndarray
    sigma_deg: float = 1.0

    def stage_part(self, dT: np.ndarray, dS: np.ndarray) -> np.ndarray:
        """``[V, 3, 3]`` ``diag(1,-1,-1) Rx(T + dT) Rz(S + dS)`` (corrections in radians)."""
        T, S = np.radians(self.tilt) + dT, np.radians(self.rotation) + dS
        return np.stack([_C0 @ rot_x(a) @ rot_z(b) for a, b in zip(T, S)])


def residuals(views: OrthoViews, X: np.ndarray, obs: Observations) -> np.ndarray:
    """``[n]`` reprojection error (pixels) of each observation."""
    return np.linalg.norm(views.project(X, obs) - obs.uv, axis=1)


class _Problem:
    """Parameter layout and the residual / Jacobian functions of one adjustment.

    Per view ``k`` local columns: rotation (3: ``w`` free, or ``q`` shared), [stage: ``dT, dS``], ``t`` (2),
    [``log m``]; ``index [V, k]`` maps them to parameters (-1: held; shared columns map alike for all views).
    """

    def __init__(self, views: OrthoViews, obs: Observations, fixed: int, per_view_scale: bool,
                 stage: StageModel | None):
        V = len(views)
        self.views, self.obs, self.stage, self.per_view_scale = views, obs, stage, per_view_scale
        self.r0 = 5 if stage is not None else 3                       # first translation column
        self.k = self.r0 + 2 + int(per_view_scale)
        free = np.ones((V, self.k), bool)
        if stage is None:
            free[fixed, :3] = False
        free[fixed, self.r0:self.r0 + 2] = False
        if per_view_scale:
            free[fixed, -1] = False
        lever = np.abs(np.einsum("vij,j->vi", views.R[:, :2, :], views.R[fixed, 2]))
        lever[fixed] = -1
        v, c = np.unravel_index(int(lever.argmax()), lever.shape)
        free[v, self.r0 + c] = False                                  # the translation gauge along view fixed's axis
        index = np.full((V, self.k), -1, np.int64)
        if stage is not None:
            index[:, :3] = np.arange(3)
            free[:, :3] = False
        index[free] = 3 * (stage is not None) + np.arange(int(free.sum()))
        self.index, self.n_params = index, int(index.max()) + 1
        self._cache: tuple[bytes, tuple] | None = None
        if stage is not None:  # prior weight per view: sqrt(observations) / sigma (module docstring)
            n_view = np.bincount(obs.vi, minlength=V).astype(float)
            self.prior_weight = np.repeat(np.sqrt(np.maximum(n_view, 1.0)), 2) / np.radians(stage.sigma_deg)

    def _local(self, p: np.ndarray) -> np.ndarray:
        return local_values(self.index, p)

    def views_at(self, p: np.ndarray) -> OrthoViews:
        full = self._local(p)
        if self.stage is None:
            R = rodrigues(full[:, :3]) @ self.views.R
        else:
            R = rodrigues(full[:1, :3])[0] @ self.stage.Q @ self.stage.stage_part(full[:, 3], full[:, 4])
        t = self.views.t + full[:, self.r0:self.r0 + 2]
        s = self.views.scale * (np.exp(full[:, -1]) if self.per_view_scale else 1.0)
        return OrthoViews(R, t, s)

    def _state(self, p: np.ndarray):
        key = p.tobytes()
        if self._cache is None or self._cache[0] != key:
            views = self.views_at(p)
            self._cache = (key, (views, views.triangulate(self.obs)))
        return self._cache[1]

    def prior(self, p: np.ndarray) -> np.ndarray:
        if self.stage is None:
            return np.zeros(0)
        return self._local(p)[:, 3:5].ravel() * self.prior_weight

    def fun(self, p: np.ndarray) -> np.ndarray:
        views, X = self._state(p)
        return np.concatenate([(views.project(X, self.obs) - self.obs.uv).ravel(), self.prior(p)])

    def _local_jacobian(self, p: np.ndarray, views: OrthoViews, X: np.ndarray) -> np.ndarray:
        """``[n, 2, k]`` derivatives of each observation's pixel by its view's local columns."""
        o, full = self.obs, self._local(p)
        Xw = X[o.pj]
        cam = np.einsum("nij,nj->ni", views.R[o.vi], Xw)
        s = views.scale[o.vi]
        J = np.zeros((len(o), 2, self.k))
        w = full[:, :3] if self.stage is None else np.broadcast_to(full[:1, :3], (len(views), 3))
        J[:, :, :3] = -s[:, None, None] * np.einsum("nij,njk->nik", skew(cam)[:, :2, :], left_jacobian(w)[o.vi])
        if self.stage is not None:
            # R = pre Rz(S) with pre = exp([q]) Q C0 Rx(T): dR X / dT = pre (e_x x Rz X), dR X / dS = R (e_z x X)
            Rz = np.stack([rot_z(a) for a in np.radians(self.stage.rotation) + full[:, 4]])
            pre = views.R @ np.transpose(Rz, (0, 2, 1))
            zx = np.einsum("nij,nj->ni", Rz[o.vi], Xw)
            J[:, :, 3] = s[:, None] * np.einsum("nij,nj->ni", pre[o.vi, :2, :], np.cross([1.0, 0, 0], zx))
            J[:, :, 4] = s[:, None] * np.einsum("nij,nj->ni", views.R[o.vi, :2, :], np.cross([0, 0, 1.0], Xw))
        J[:, 0, self.r0] = J[:, 1, self.r0 + 1] = 1.0
        if self.per_view_scale:
            J[:, :, -1] = s[:, None] * cam[:, :2]
        return J

    def jac(self, p: np.ndarray):
        from scipy.sparse import coo_matrix, vstack

        views, X = self._state(p)
        o = self.obs
        G = views.scale[o.vi, None, None] * views.R[o.vi, :2, :]       # [n, 2, 3] d uv / d X
        data = eliminated_jacobian(self._local_jacobian(p, views, X), G, o, self.index, self.n_params)
        if self.stage is None:
            return data
        prior_cols = self.index[:, 3:5].ravel()
        prior = coo_matrix((self.prior_weight, (np.arange(len(prior_cols)), prior_cols)),
                           shape=(len(prior_cols), self.n_params))
        return vstack([data, prior]).tocsr()


def local_values(index: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[V, k]`` each view's local columns from the parameters ``p`` through ``index [V, k]`` (0 where held: -1)."""
    full = np.zeros(index.shape)
    full[index >= 0] = p[index[index >= 0]]
    return full


def eliminated_jacobian(J: np.ndarray, G: np.ndarray, obs: Observations, index: np.ndarray, n_params: int):
    """Sparse ``[2n, n_params]`` Jacobian of the residuals with the points eliminated (Kaufman's form, module
    docstring) from the views' local Jacobian ``J [n, 2, k]`` and the points' ``G [n, 2, 3]``; ``index [V, k]``
    maps a view's local columns to parameters (-1: held)."""
    from scipy.sparse import coo_matrix

    o, n = obs, len(obs)
    A = np.zeros((o.n_points, 3, 3))
    np.add.at(A, o.pj, np.einsum("nki,nkj->nij", G, G))
    A_inv = np.linalg.inv(A + 1e-9 * np.eye(3))
    order = np.argsort(o.pj, kind="stable")
    counts = np.bincount(o.pj, minlength=o.n_points)
    k1, k2 = _pairs(order, counts, np.concatenate([[0], np.cumsum(counts)[:-1]]))
    GA = np.einsum("nij,njk->nik", G, A_inv[o.pj])
    blocks = -np.einsum("mij,mkj,mkl->mil", GA[k1], G[k2], J[k2])     # rows k1, columns of view(k2)
    own = k1 == k2
    blocks[own] += J[k1[own]]
    rows = np.broadcast_to(((2 * k1)[:, None] + np.arange(2))[:, :, None], blocks.shape)
    cols = np.broadcast_to(index[o.vi[k2]][:, None, :], blocks.shape)
    keep = cols >= 0
    return coo_matrix((blocks[keep], (rows[keep], cols[keep])), shape=(2 * n, n_params)).tocsr()


def bundle_adjust(views: OrthoViews, obs: Observations, *, stage: StageModel | None = None, fixed: int = 0,
                  per_view_scale: bool = False, loss: str = "huber", f_scale: float = 1.0, max_nfev: int = 100
                  ) -> tuple[OrthoViews, np.ndarray, dict]:
    """Refine ``views`` on ``obs`` (module docstring); ``stage`` selects the stage model (its ``Q`` and angles
    must reproduce ``views.R``). Returns the views, their points ``[N, 3]`` and the optimiser's summary
    (``cost, nfev, status, message``; with ``stage``: ``dtilt_deg, drotation_deg [V]`` and the updated model)."""
    from scipy.optimize import least_squares

    prob = _Problem(views, obs, fixed, per_view_scale, stage)
    res = least_squares(prob.fun, np.zeros(prob.n_params), jac=lambda p: prob.jac(p).toarray(), method="trf",
                        loss=loss, f_scale=f_scale, x_scale="jac", tr_solver="exact", max_nfev=max_nfev)
    out = prob.views_at(res.x)
    U, _, Vt = np.linalg.svd(out.R)                                      # remove round-off
    out = replace(out, R=U @ Vt)
    info = {"cost": float(res.cost), "nfev": int(res.nfev), "status": int(res.status), "message": res.message}
    if stage is not None:
        full = prob._local(res.x)
        info["dtilt_deg"] = np.degrees(full[:, 3]).tolist()
        info["drotation_deg"] = np.degrees(full[:, 4]).tolist()
        info["stage"] = StageModel(stage.tilt + np.degrees(full[:, 3]), stage.rotation + np.degrees(full[:, 4]),
                                   rodrigues(full[:1, :3])[0] @ stage.Q, stage.sigma_deg)
    return out, out.triangulate(obs), info
