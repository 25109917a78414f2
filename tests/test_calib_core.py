"""Calibration maths: the stage model, the linear solves, matching, tracks and the bundle adjustment."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from arcsem.calib.bundle import OrthoViews, StageModel, _Problem, bundle_adjust, residuals
from arcsem.calib.geometry import project, rot_z, solve_points_translations, stage_rotation
from arcsem.calib.matching import PairMatches, match_descriptors, ransac_affine_fundamental
from arcsem.calib.tracks import Observations, build_tracks


def scene(V=7, N=120, seed=0, noise=0.0, axis=7.0):
    """Views on a tilt series with stage rotations; every point seen by 2+ views."""
    rng = np.random.default_rng(seed)
    tilt, rot = np.linspace(-24, 24, V), rng.normal(0, 15, V)
    R = np.stack([stage_rotation(t, r, axis) for t, r in zip(tilt, rot)])
    X = rng.normal(size=(N, 3))
    X -= X.mean(0)
    s, t = np.full(V, 40.0), rng.normal(0, 50, (V, 2))
    vi, pj = (a.ravel() for a in np.meshgrid(np.arange(V), np.arange(N), indexing="ij"))
    keep = (rng.random(len(vi)) < 0.6) | (vi < 2)
    vi, pj = vi[keep], pj[keep]
    uv = project(R, t, s, X, vi, pj) + rng.normal(0, noise, (len(vi), 2))
    return (tilt, rot, R, X, s, t), Observations(vi, pj, uv, np.zeros(len(vi), int), N)


def test_stage_model_reproduces_the_synthetic_arcs():
    from arcsem.synthetic.cameras import arc_cameras, arc_views

    views = arc_views(8, 5)
    cams, _ = arc_cameras(views, 96, 64, "orthographic")
    for v, R in zip(views, cams.world_to_cam[:, :3, :3].numpy()):
        # the horizontal arc is a stage rotation at 80 degrees of tilt, the vertical one a tilt series
        np.testing.assert_allclose(stage_rotation(v.elevation - 90, -v.azimuth), R, atol=1e-12)


def test_linear_solve_is_exact_without_noise():
    (_, _, R, X, s, t), obs = scene()
    X2, t2 = solve_points_translations(R, s, obs.vi, obs.pj, obs.uv, obs.n_points)
    np.testing.assert_allclose(X2, X, atol=1e-8)   # the true points have zero mean: the same gauge
    np.testing.assert_allclose(t2, t, atol=1e-7)


@pytest.mark.parametrize("stage", [False, True])
@pytest.mark.parametrize("per_view_scale", [False, True])
def test_jacobian_matches_finite_differences(stage, per_view_scale):
    (tilt, rot, R, _, s, t), obs = scene()
    model = StageModel(tilt, rot, rot_z(np.radians(7.0))) if stage else None
    prob = _Problem(OrthoViews(R, t, s), obs, 0, per_view_scale, model)
    p = np.zeros(prob.n_params)  # at the solution (zero residual) Kaufman's Jacobian is the exact one
    J = prob.jac(p).toarray()
    num = np.stack([(prob.fun(p + 1e-6 * e) - prob.fun(p - 1e-6 * e)) / 2e-6 for e in np.eye(prob.n_params)], 1)
    np.testing.assert_allclose(J, num, atol=1e-6 * np.abs(num).max())
    assert np.linalg.matrix_rank(J) == prob.n_params   # the gauges are removed


def angles(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.einsum("nij,nij->n", Ra, Rb) - 1) / 2, -1, 1)))


def test_bundle_adjustment_recovers_perturbed_rotations():
    (tilt, rot, R, _, s, _t), obs = scene(noise=0.1)
    rng = np.random.default_rng(1)
    Rp = np.stack([stage_rotation(a + rng.normal(0, 1.5), b + rng.normal(0, 1.5), 7 + rng.normal(0, 1))
                   for a, b in zip(tilt, rot)])
    Rp[0] = R[0]
    start = OrthoViews(Rp, solve_points_translations(Rp, s, obs.vi, obs.pj, obs.uv, obs.n_points)[1], s)
    views, X, _info = bundle_adjust(start, obs, max_nfev=50)
    assert angles(views.R, R).max() < 0.2  # noise 0.1 px at 40 px per unit: ~0.1 deg
    assert angles(Rp, R).max() > 1.0
    assert np.sqrt(np.mean(residuals(views, X, obs) ** 2)) < 0.15


def test_stage_bundle_adjustment_fits_the_axis_and_corrections():
    (tilt, rot, R, _, s, _t), obs = scene(noise=0.05)
    model = StageModel(tilt, rot, rot_z(np.radians(4.0)), sigma_deg=1.0)  # axis off by 3 degrees
    start_R = model.Q @ model.stage_part(np.zeros(len(tilt)), np.zeros(len(tilt)))
    start = OrthoViews(start_R, solve_points_translations(start_R, s, obs.vi, obs.pj, obs.uv, obs.n_points)[1], s)
    views, _, info = bundle_adjust(start, obs, stage=model, max_nfev=50)
    assert angles(views.R, R).max() < 0.05 < angles(start_R, R).min()
    np.testing.assert_allclose(info["stage"].Q, rot_z(np.radians(7.0)), atol=1e-3)


def test_match_descriptors_equals_brute_force():
    rng = np.random.default_rng(0)
    da = rng.normal(size=(300, 32)).astype(np.float32)
    da /= np.linalg.norm(da, axis=1, keepdims=True)
    db = da[rng.permutation(300)[:250]] + 0.1 * rng.normal(size=(250, 32)).astype(np.float32)
    db /= np.linalg.norm(db, axis=1, keepdims=True)
    d = np.sqrt(np.maximum(2 - 2 * da @ db.T, 0))
    o, oc = np.argsort(d, 1), np.argsort(d, 0)
    ok = (d[np.arange(300), o[:, 0]] < 0.8 * d[np.arange(300), o[:, 1]]) & (oc[0][o[:, 0]] == np.arange(300))
    ok &= (d[oc[0], np.arange(250)] < 0.8 * d[oc[1], np.arange(250)])[o[:, 0]]
    ia, ib = match_descriptors(da, db, chunk=64)
    np.testing.assert_array_equal(ia, np.nonzero(ok)[0])
    np.testing.assert_array_equal(ib, o[ok, 0])
    assert len(ia) > 100


def test_ransac_affine_fundamental_finds_the_inliers():
    (_, _, R, X, s, t), _ = scene(N=200)
    xa, xb = (project(R, t, s, X, np.full(200, v), np.arange(200)) for v in (0, 3))
    rng = np.random.default_rng(2)
    bad = rng.random(200) < 0.3
    xb[bad] += rng.uniform(-40, 40, (bad.sum(), 2))
    inl, normal = ransac_affine_fundamental(xa, xb, threshold=1.0)
    assert (inl == ~bad).mean() > 0.98 and abs(np.linalg.norm(normal) - 1) < 1e-9


def test_tracks_join_matches_and_drop_conflicts():
    kp = [np.arange(10.0).reshape(5, 2)] * 3
    m = [PairMatches(0, 1, np.array([0, 1, 2]), np.array([0, 1, 3]), np.zeros(4)),
        PairMatches(1, 2, np.array([0, 3, 1]), np.array([4, 2, 1]), np.zeros(4)),
        PairMatches(0, 2, np.array([2, 4]), np.array([0, 3]), np.zeros(4))]
    obs = build_tracks(m, kp)
    tracks = sorted(tuple(sorted(zip(obs.vi[obs.pj == j].tolist(), obs.fi[obs.pj == j].tolist())))
                    for j in range(obs.n_points))
    # (0,2)-(1,3)-(2,2) and (0,2)-(2,0): feature 2 of view 0 meets features 2 and 0 of view 2: dropped
    assert tracks == [((0, 0), (1, 0), (2, 4)), ((0, 1), (1, 1), (2, 1)), ((0, 4), (2, 3))]
    assert torch.tensor(obs.uv).shape == (len(obs), 2)


def test_refinement_recovers_a_subpixel_shift_under_exposure_change():
    import cv2

    from arcsem.calib.features import detect_features
    from arcsem.calib.refine import refine_observations

    rng = np.random.default_rng(0)
    big = cv2.GaussianBlur(rng.normal(0, 1, (480, 640)), (0, 0), 6)
    big = (128 + 40 * big / big.std()).astype(np.float32)
    shift = np.array([0.3, -0.7])  # pixels of the small images
    moved = cv2.warpAffine(big, np.float32([[1, 0, 4 * shift[0]], [0, 1, 4 * shift[1]]]), (640, 480),
                           flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    small = lambda im: np.clip(cv2.resize(im, (160, 120), interpolation=cv2.INTER_AREA), 0, 255).astype(np.uint8)
    a, b = small(big), small(0.7 * moved + 40)  # another exposure
    f = detect_features(a, 300)
    keep = np.all((f.xy > 12) & (f.xy < [148, 108]), 1)
    xy = f.xy[keep]
    n = len(xy)
    start = xy + shift + rng.normal(0, 0.5, (n, 2))
    # view 0 holds the references (track middle = the second observation in view order: view 1 is refined)
    obs = Observations(np.r_[np.zeros(n, int), np.ones(n, int)], np.r_[np.arange(n), np.arange(n)],
                       np.r_[xy, start], np.zeros(2 * n, int), n)
    out, info = refine_observations([b, a], Observations(1 - obs.vi, obs.pj, obs.uv, obs.fi, n))
    refined = out.uv[out.vi == 0]
    err = np.linalg.norm(refined - (xy[out.pj[out.vi == 0]] + shift), axis=1)
    assert n > 20 and info["refined"] > 0.8 * n
    # the summary adds up: every candidate is refined or dropped for its fit; nothing here is beyond the angle
    assert info["refined"] + info["fit_failed"] == info["candidates"] == n and info["beyond_angle"] == 0
    assert info["dropped"] == info["fit_failed"] + info["beyond_angle"] == n - int((out.vi == 0).sum())
    assert np.median(err) < 0.08 < np.median(np.linalg.norm(start - xy - shift, axis=1))


def aligned_angles(R_true: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Per-view angles (deg) between ``R`` and ``R_true`` after the best common world rotation (no mirror)."""
    U, _, Vt = np.linalg.svd(np.einsum("nji,njk->ik", R, R_true))
    Q = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return angles(np.einsum("nij,jk->nik", R, Q), R_true)


def test_factorization_recovers_the_views_up_to_the_depth_reversal():
    from arcsem.calib.factorization import init_factorization

    (_, _, R, _, s, _t), obs = scene()
    views, _, block = init_factorization(obs, len(R), s[0])
    mirrored = np.diag([-1.0, -1.0, 1.0]) @ views.R
    best = min(aligned_angles(R, views.R).max(), aligned_angles(R, mirrored).max())
    assert len(block) >= 3 and best < 1e-4
    np.testing.assert_allclose(residuals(views, views.triangulate(obs), obs), 0, atol=1e-6)


def grain_on_substrate(seed=0):
    """The synthetic scene's arcs (its substrate normal ~66 deg from the mean viewing direction) over a ball of
    radius 0.9 standing on the plane z = -1 (a 4 x 4 patch of it)."""
    from arcsem.synthetic.cameras import arc_views

    rng = np.random.default_rng(seed)
    R = np.stack([stage_rotation(v.elevation - 90, -v.azimuth) for v in arc_views(8, 5) if v.split == "train"])
    ball = rng.normal(size=(150, 3))
    ball = 0.9 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    ground = np.c_[rng.uniform(-2, 2, (150, 2)), np.full(150, -1.0)]
    return OrthoViews(R, np.zeros((len(R), 2)), np.full(len(R), 40.0)), np.r_[ball, ground]


@pytest.mark.parametrize("reversed_", [False, True])
def test_factorised_frame_puts_the_specimen_in_front_of_its_substrate(reversed_):
    from arcsem.calib.frame import mirror, world_frame

    truth, X = grain_on_substrate()
    views, Xm = mirror(truth, X) if reversed_ else (truth, X)
    out, _, frame = world_frame(views, Xm, stage_frame=False)
    back = -truth.R[:, 2, :].mean(0)
    assert np.degrees(np.arccos(back[2] / np.linalg.norm(back))) > 60   # the case the 45/60-deg limits missed
    assert frame.substrate is not None and frame.substrate[150:].all() and frame.mirrored == reversed_
    assert aligned_angles(truth.R, out.R).max() < 1e-4
    assert np.median(frame.height[:150]) > 0                           # the ball on the cameras' side


def test_the_specimen_box_leaves_out_points_just_off_the_substrate():
    """Substrate points scattered a little off the plane (noise, a slightly curved substrate) are neither the
    substrate's inliers nor the specimen: the frame's origin and the specimen points must ignore them."""
    from arcsem.calib.frame import specimen_points, world_frame

    rng = np.random.default_rng(1)
    views, X = grain_on_substrate()
    ground = np.c_[rng.uniform(-6, 6, (600, 2)), -1.0 + rng.normal(0, 0.002, 600)]   # a wide, slightly rough plane
    ground[:20, 2] = -1.0 + rng.uniform(0.009, 0.014, 20)  # and some just off it: above by 1.5-2.2 tolerances,
    ground[20:40, 2] -= rng.uniform(0.009, 0.05, 20)       # and below
    ground[:40, 0] = rng.uniform(-6, -4, 40)                                          # on one side, far out
    X = np.r_[X[:150], ground]
    _, Xw, frame = world_frame(views, X, stage_frame=True)
    spec = specimen_points(frame.substrate, frame.height, Xw)
    assert spec[:150].mean() > 0.95 and not spec[150:].any()
    box = np.percentile(Xw[spec], 99, axis=0) - np.percentile(Xw[spec], 1, axis=0)
    assert box[:2].max() < 2.0                                       # the ball's 1.8, not the plane's 12
    assert np.abs(Xw[:150].mean(0)[:2]).max() < 0.1                  # the origin at the ball's centre
    assert specimen_points(None, None, np.zeros((5, 3))).all()


def test_debris_far_out_on_the_substrate_is_left_out_of_the_specimen_box_and_the_origin():
    """A small cluster standing on the substrate far from the grain (debris) is above the substrate like the grain.
    Counted in, its 1-99 percentiles stretched the built-in scene's specimen box six times and moved the origin off
    the grain; the specimen points leave it out."""
    from arcsem.calib.frame import above_substrate, specimen_points, world_frame

    rng = np.random.default_rng(2)
    views, X = grain_on_substrate()
    ground = np.c_[rng.uniform(-6, 6, (600, 2)), np.full(600, -1.0)]
    debris = np.c_[rng.normal(-5.0, 0.05, (20, 2)), -1.0 + rng.uniform(0.1, 0.3, 20)]   # 20 points, 2 % of all
    X = np.r_[X[:150], ground, debris]
    _, Xw, frame = world_frame(views, X, stage_frame=True)
    above = above_substrate(frame.substrate, frame.height, len(X))
    spec = specimen_points(frame.substrate, frame.height, Xw)
    assert above[750:].all() and not spec[750:].any() and spec[:150].mean() > 0.95
    box = np.percentile(Xw[spec], 99, axis=0) - np.percentile(Xw[spec], 1, axis=0)
    assert box[:2].max() < 2.0                                       # the ball's 1.8, not 7 with the debris
    assert np.abs(Xw[:150].mean(0)[:2]).max() < 0.1                  # the origin at the ball's centre
