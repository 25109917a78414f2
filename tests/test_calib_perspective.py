"""Perspective refinement of calibrated views (``arcsem-calibrate --camera perspective``)."""
from __future__ import annotations

import numpy as np
import pytest

from arcsem.calib.bundle import OrthoViews
from arcsem.calib.geometry import project, rodrigues, stage_rotation
from arcsem.calib.perspective import PinholeViews, _Problem, from_ortho, perspective_adjust
from arcsem.calib.tracks import Observations

CENTRE = np.array([288.0, 192.0])


def far_pinhole(V=12, N=300, noise=0.0, seed=0, focal=9375.0, distance=58.0):
    """A tilt series of the paper's far pinhole around points in a unit ball; every point seen by 2+ views."""
    rng = np.random.default_rng(seed)
    R = np.stack([stage_rotation(t, r, 7.0) for t, r in zip(np.linspace(-30, 30, V), rng.normal(0, 10, V))])
    T = np.c_[rng.normal(0, 0.05, (V, 2)), np.full(V, distance)]
    X = rng.normal(size=(N, 3))
    X *= rng.uniform(0.3, 1.0, (N, 1)) / np.linalg.norm(X, axis=1, keepdims=True)
    vi, pj = (a.ravel() for a in np.meshgrid(np.arange(V), np.arange(N), indexing="ij"))
    keep = (rng.random(len(vi)) < 0.7) | (vi < 2)
    vi, pj = vi[keep], pj[keep]
    views = PinholeViews(R, T, focal, CENTRE)
    obs = Observations(vi, pj, np.zeros((len(vi), 2)), np.zeros(len(vi), int), N)
    obs.uv = views.project(X, obs) + rng.normal(0, noise, (len(vi), 2))
    return views, X, obs


def test_from_ortho_gives_the_same_pixels_at_the_origins_depth():
    rng = np.random.default_rng(1)
    R = np.stack([stage_rotation(t, 0.0) for t in (-10.0, 0.0, 12.0)])
    ortho = OrthoViews(R, rng.normal(0, 20, (3, 2)) + CENTRE, np.array([160.0, 161.0, 159.0]))
    pin = from_ortho(ortho, 9375.0, CENTRE)
    for v in range(3):
        X = rng.normal(size=(50, 3))
        X -= np.outer(X @ R[v, 2], R[v, 2])           # points in the plane through the origin facing view v
        obs = Observations(np.full(50, v), np.arange(50), None, None, 50)
        np.testing.assert_allclose(pin.project(X, obs), project(ortho.R, ortho.t, ortho.scale, X, obs.vi, obs.pj),
                                   atol=1e-9)
    np.testing.assert_allclose(pin.scale, ortho.scale)


@pytest.mark.parametrize("estimate_focal", [False, True])
def test_jacobian_matches_finite_differences(estimate_focal):
    views, X, obs = far_pinhole()
    prob = _Problem(views, obs, X, 0, estimate_focal)
    p = np.zeros(prob.n_params)  # at the solution (zero residual) Kaufman's Jacobian is the exact one
    J = prob.jac(p).toarray()
    h = 1e-7
    num = np.stack([(prob.fun(p + h * e) - prob.fun(p - h * e)) / (2 * h) for e in np.eye(prob.n_params)], 1)
    np.testing.assert_allclose(J, num, atol=1e-5 * np.abs(num).max())
    assert np.linalg.matrix_rank(J) == prob.n_params   # the gauges are removed


def test_triangulation_recovers_the_points():
    views, X, obs = far_pinhole()
    start = X * 1.05 + 0.02
    np.testing.assert_allclose(views.triangulate(obs, start), X, atol=1e-8)


def angles(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.einsum("nij,nij->n", Ra, Rb) - 1) / 2, -1, 1)))


def test_adjustment_recovers_rotations_and_focal_from_a_wrong_focal():
    truth, X, obs = far_pinhole(noise=0.1)
    rng = np.random.default_rng(3)
    # start: twice the focal at twice the distance (same magnification), rotations off by ~0.3 degrees
    R0 = rodrigues(rng.normal(0, np.radians(0.3), (len(truth), 3))) @ truth.R
    R0[0] = truth.R[0]                                   # the held view carries the gauge
    start = PinholeViews(R0, truth.T * 2.0, 2.0 * truth.focal, CENTRE)
    views, Xa, _ = perspective_adjust(start, start.triangulate(obs, 2.0 * X), obs)
    assert angles(views.R, truth.R).max() < 0.05
    assert views.focal == pytest.approx(truth.focal, rel=0.03)
    assert views.scale[0] == pytest.approx(start.scale[0])   # the world unit of the held view is kept
    rms = np.sqrt(np.mean(np.sum((views.project(Xa, obs) - obs.uv) ** 2, 1)))
    assert rms < 0.1 * np.sqrt(2) * 1.1


def test_a_held_focal_stays():
    truth, X, obs = far_pinhole(noise=0.1)
    views, _, info = perspective_adjust(truth, X, obs, estimate_focal=False)
    assert views.focal == truth.focal and info["focal_px"] == truth.focal


def test_the_rotation_prior_has_its_jacobian_and_holds_the_start():
    truth, X, obs = far_pinhole(noise=0.1)
    prob = _Problem(truth, obs, X, 0, True, sigma_deg=1.0)
    rng = np.random.default_rng(5)
    p = rng.normal(0, 1e-4, prob.n_params)
    J = prob.jac(p).toarray()
    n = 2 * len(obs)
    h = 1e-7
    num = np.stack([(prob.fun(p + h * e) - prob.fun(p - h * e)) / (2 * h) for e in np.eye(prob.n_params)], 1)
    np.testing.assert_allclose(J[n:], num[n:], atol=1e-9 * np.abs(num[n:]).max())   # the prior rows: exact
    R0 = rodrigues(rng.normal(0, np.radians(0.5), (len(truth), 3))) @ truth.R
    R0[0] = truth.R[0]
    start = PinholeViews(R0, truth.T, truth.focal, CENTRE)
    free, _, _ = perspective_adjust(start, X, obs, estimate_focal=False)
    held, _, _ = perspective_adjust(start, X, obs, estimate_focal=False, sigma_deg=1e-3)
    assert angles(held.R, R0).max() < 0.2 * angles(free.R, R0).max()
