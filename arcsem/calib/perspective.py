"""Perspective (far pinhole) refinement of calibrated views: ``arcsem-calibrate --camera perspective``.

An SEM's projection is parallel only in the limit: the beam is scanned by deflecting it about a pivot point
above the specimen, so at low magnification (a field of view that is not small against the distance to the
pivot) the projection is central with a long focal length. The paper's authors calibrated their series as
a pinhole of ~50,000 px focal at 3072 px width. Where the perspective is measurable, the orthographic
cameras of :mod:`.bundle` leave a depth-dependent magnification error (``z / D`` of a point at depth ``z``
for a camera at distance ``D``) that the robust loss partly hides by rejecting the affected observations.

A pinhole view ``i`` projects ``u = f (R_i X + T_i)_xy / (R_i X + T_i)_z + c`` (OpenCV axes, ``c`` the image
centre, ``f`` one focal length in pixels shared by all views). It starts from an orthographic view
(:func:`from_ortho`: the same pixels at the origin's depth, ``D_i = f / s_i``) and is adjusted like
:mod:`.bundle`'s views: the points are eliminated (for given views each point is the Gauss-Newton
least-squares solution of its observations, :meth:`PinholeViews.triangulate`; the Jacobian is Kaufman's form,
:func:`~.bundle.eliminated_jacobian`). Per view a rotation increment ``w_i`` and the translation ``T_i``; view
``fixed`` is held (the rotation and translation gauge) and one coordinate of another view's translation (the
scale gauge); ``log f`` is shared, estimated or held. The perspective of a far pinhole changes the pixels by a
fraction of a pixel, too little to determine the angular steps along an arc anew (the depth / angle trade of
:mod:`.bundle`): where the orthographic rotations came from stage angles, a prior ``sqrt(n_i) w_i / sigma``
(``n_i`` observations of view ``i``, ``sigma`` the stage prior's) keeps them near their start. After
the adjustment the world is rescaled so that view ``fixed`` keeps its orthographic scale at the origin (the
world unit stays the one of the pixel size).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .bundle import OrthoViews, eliminated_jacobian, local_values
from .geometry import left_jacobian, rodrigues, skew
from .tracks import Observations

__all__ = ["PinholeViews", "from_ortho", "perspective_adjust"]


@dataclass
class PinholeViews:
    """``V`` pinhole views: ``R [V, 3, 3]`` world -> camera, ``T [V, 3]`` (camera = ``R X + T``), one ``focal``
    in pixels, principal point ``centre [2]`` in pixels."""

    R: np.ndarray
    T: np.ndarray
    focal: float
    centre: np.ndarray

    def __len__(self) -> int:
        return len(self.R)

    @property
    def scale(self) -> np.ndarray:
        """``[V]`` pixels per world unit at the depth of the world origin."""
        return self.focal / self.T[:, 2]

    def camera_points(self, X: np.ndarray, obs: Observations) -> np.ndarray:
        """``[n, 3]`` camera coordinates of the observed points."""
        return np.einsum("nij,nj->ni", self.R[obs.vi], X[obs.pj]) + self.T[obs.vi]

    def project(self, X: np.ndarray, obs: Observations) -> np.ndarray:
        """``[n, 2]`` pixels of the points ``X [N, 3]`` at the observations."""
        cam = self.camera_points(X, obs)
        return self.focal * cam[:, :2] / cam[:, 2:] + self.centre

    def point_jacobian(self, cam: np.ndarray) -> np.ndarray:
        """``[n, 2, 3]`` derivative of the pixels by the camera coordinates ``cam [n, 3]``."""
        z = cam[:, 2]
        P = np.zeros((len(cam), 2, 3))
        P[:, 0, 0] = P[:, 1, 1] = self.focal / z
        P[:, :, 2] = -self.focal * cam[:, :2] / z[:, None] ** 2
        return P

    def triangulate(self, obs: Observations, X0: np.ndarray, iters: int = 10, tol: float = 1e-10) -> np.ndarray:
        """``[N, 3]`` least-squares points of ``obs`` (Gauss-Newton per point from ``X0 [N, 3]``)."""
        X = X0.copy()
        for _ in range(iters):
            cam = self.camera_points(X, obs)
            G = np.einsum("nij,njk->nik", self.point_jacobian(cam), self.R[obs.vi])      # [n, 2, 3]
            r = self.focal * cam[:, :2] / cam[:, 2:] + self.centre - obs.uv
            A = np.zeros((obs.n_points, 3, 3))
            np.add.at(A, obs.pj, np.einsum("nki,nkj->nij", G, G))
            b = np.zeros((obs.n_points, 3))
            np.add.at(b, obs.pj, np.einsum("nki,nk->ni", G, r))
            step = np.linalg.solve(A + 1e-9 * np.eye(3), b[..., None])[..., 0]
            X -= step
            if np.abs(step).max() <= tol * (1.0 + np.abs(X).max()):
                break
        return X


def from_ortho(views: OrthoViews, focal: float, centre: np.ndarray) -> PinholeViews:
    """Pinhole views giving ``views``' pixels at the origin's depth: ``D_i = f / s_i``, ``T_xy = (t_i - c) / s_i``."""
    T = np.concatenate([(views.t - centre) / views.scale[:, None], (focal / views.scale)[:, None]], 1)
    return PinholeViews(views.R.copy(), T, float(focal), np.asarray(centre, float))


class _Problem:
    """Columns per view: ``w`` (3), ``T`` (3), ``log f`` (1, shared); ``index [V, 7]`` maps them (-1: held)."""

    def __init__(self, views: PinholeViews, obs: Observations, X0: np.ndarray, fixed: int, estimate_focal: bool,
                 sigma_deg: float | None = None):
        V = len(views)
        self.views, self.obs, self.X = views, obs, X0
        index = np.full((V, 7), -1, np.int64)
        free = np.ones((V, 6), bool)
        free[fixed] = False
        # scaling the world about view fixed's centre moves view i's T by its baseline R_i (C_fixed - C_i): one
        # coordinate of the longest lever is held (the scale gauge)
        C = -np.einsum("vji,vj->vi", views.R, views.T)
        lever = np.abs(np.einsum("vij,vj->vi", views.R, C[fixed] - C))
        lever[fixed] = -1
        v, c = np.unravel_index(int(lever.argmax()), lever.shape)
        free[v, 3 + c] = False
        index[:, :6][free] = np.arange(int(free.sum()))
        if estimate_focal:
            index[:, 6] = int(free.sum())
        self.index, self.n_params = index, int(index.max()) + 1
        self._cache: tuple[bytes, tuple] | None = None
        self.prior_weight = None
        if sigma_deg is not None:  # per view sqrt(observations) / sigma on each rotation column, as .bundle's stage prior
            n_view = np.bincount(obs.vi, minlength=V).astype(float)
            self.prior_weight = np.repeat(np.sqrt(np.maximum(n_view, 1.0)), 3) / np.radians(sigma_deg)

    def _local(self, p: np.ndarray) -> np.ndarray:
        return local_values(self.index, p)

    def views_at(self, p: np.ndarray) -> PinholeViews:
        full = self._local(p)
        return PinholeViews(rodrigues(full[:, :3]) @ self.views.R, self.views.T + full[:, 3:6],
                            self.views.focal * float(np.exp(full[0, 6])), self.views.centre)

    def state(self, p: np.ndarray):
        key = p.tobytes()
        if self._cache is None or self._cache[0] != key:
            views = self.views_at(p)
            X = views.triangulate(self.obs, self.X)
            self.X = X  # the next solve starts here (Gauss-Newton converges from any nearby start)
            self._cache = (key, (views, X))
        return self._cache[1]

    def prior(self, p: np.ndarray) -> np.ndarray:
        return np.zeros(0) if self.prior_weight is None else self._local(p)[:, :3].ravel() * self.prior_weight

    def fun(self, p: np.ndarray) -> np.ndarray:
        views, X = self.state(p)
        return np.concatenate([(views.project(X, self.obs) - self.obs.uv).ravel(), self.prior(p)])

    def jac(self, p: np.ndarray):
        views, X = self.state(p)
        o, full = self.obs, self._local(p)
        cam = views.camera_points(X, o)
        P = views.point_jacobian(cam)                                         # [n, 2, 3]
        rot = np.einsum("nij,nj->ni", views.R[o.vi], X[o.pj])                 # R X
        J = np.zeros((len(o), 2, 7))
        J[:, :, :3] = -np.einsum("nij,njk,nkl->nil", P, skew(rot), left_jacobian(full[:, :3])[o.vi])
        J[:, :, 3:6] = P
        J[:, :, 6] = views.focal * cam[:, :2] / cam[:, 2:]
        G = np.einsum("nij,njk->nik", P, views.R[o.vi])
        data = eliminated_jacobian(J, G, o, self.index, self.n_params)
        if self.prior_weight is None:
            return data
        from scipy.sparse import coo_matrix, vstack

        cols = self.index[:, :3].ravel()
        keep = cols >= 0
        prior = coo_matrix((self.prior_weight[keep], (np.nonzero(keep)[0], cols[keep])),
                           shape=(len(cols), self.n_params))
        return vstack([data, prior]).tocsr()


def perspective_adjust(views: PinholeViews, X0: np.ndarray, obs: Observations, *, fixed: int = 0,
                       estimate_focal: bool = True, sigma_deg: float | None = None, loss: str = "huber",
                       f_scale: float = 1.0, max_nfev: int = 100) -> tuple[PinholeViews, np.ndarray, dict]:
    """Refine pinhole ``views`` and the points (start ``X0 [N, 3]``) on ``obs`` (module docstring); ``sigma_deg``:
    a prior holding each view's rotation near its start (module docstring). Returns the views, points ``[N, 3]``
    and the optimiser's summary (``cost, nfev, status, message, focal_px``)."""
    from scipy.optimize import least_squares

    s_fixed = float(views.scale[fixed])
    prob = _Problem(views, obs, X0, fixed, estimate_focal, sigma_deg)
    res = least_squares(prob.fun, np.zeros(prob.n_params), jac=lambda p: prob.jac(p).toarray(), method="trf",
                        loss=loss, f_scale=f_scale, x_scale="jac", tr_solver="exact", max_nfev=max_nfev)
    out, X = prob.state(res.x)
    U, _, Vt = np.linalg.svd(out.R)                                      # remove round-off
    k = float(out.scale[fixed]) / s_fixed                                # world unit of the pixel size
    out = replace(out, R=U @ Vt, T=out.T * k)
    X = out.triangulate(obs, X * k)
    info = {"cost": float(res.cost), "nfev": int(res.nfev), "status": int(res.status), "message": res.message,
            "focal_px": out.focal}
    return out, X, info
