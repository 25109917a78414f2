"""Calibration of an SEM series, end to end: features, matches, tracks, initial cameras, bundle adjustment,
world frame, masks. :func:`calibrate` returns a :class:`Calibration`; :mod:`arcsem.cli.calibrate` writes it.

Protocol: every view of the folder is calibrated together; views matching ``holdout`` are marked ``test`` in
the dataset (their cameras come from the same adjustment, their pixels are never used for training).
"""
from __future__ import annotations

import fnmatch
import time
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from ..errors import DataError
from ..sem.series import Series
from .bundle import OrthoViews, StageModel, bundle_adjust, residuals
from .factorization import init_factorization
from .features import Features, detect_features, to_u8_stretched
from .frame import Frame, above_substrate, refit_substrate, specimen_points, world_frame
from .geometry import rot_z, triangulate
from .init import init_from_stage, strongest_tracks
from .masks import specimen_masks
from .matching import PairMatches, match_descriptors, ransac_affine_fundamental
from .perspective import PinholeViews, from_ortho, perspective_adjust
from .refine import refine_observations
from .tracks import Observations, build_tracks

__all__ = ["Calibration", "CalibrationOptions", "calibrate", "match_all"]


@dataclass
class CalibrationOptions:
    """Settings of :func:`calibrate` (the ``arcsem-calibrate`` flags)."""

    max_features: int = 4000        # strongest SIFT keypoints per image
    feature_scale: float | None = None  # features on a copy downscaled by this (None: longest side <= 1600 px)
    root_sift: bool = True
    ratio: float = 0.8              # Lowe's ratio test
    ransac_px: float = 2.0          # inlier distance to the affine epipolar plane, in pixels of the feature copy
    min_inliers: int = 16           # verified matches for a pair to count
    init: str = "auto"              # auto (stage angles) | stage | factorization
    per_view_scale: bool = False    # one magnification per view (drift)
    holdout: str | None = None      # glob of file names kept out of training (split=test)
    max_ba_tracks: int = 6000       # tracks in the bundle adjustment; the others are triangulated after it
    f_scale: float = 1.0            # Huber loss scale, pixels
    reject_px: float = 1.0          # observations off by more than max(this, 3 robust sigma) are dropped
    angle_sigma: float = 1.0        # degrees: prior of the stage-angle corrections (.bundle stage model)
    max_angle: float = 15.0         # degrees: an observation farther from its track's reference view is dropped
    masks: bool = True
    refine: bool = True             # sub-pixel refinement of the observations at full resolution (.refine)
    flip_depth: bool = False        # the mirrored relief (microscopes that tilt the other way; .init, .frame)
    camera: str = "orthographic"    # orthographic | perspective (a far pinhole refined from it: .perspective)
    focal_px: float | None = None   # perspective: hold this focal length (pixels); None: estimate it
    dense_features: int = 12000     # keypoints per view of the dense start (.dense; 0: the sparse points only)


@dataclass
class Calibration:
    """Result: views and points in the world frame (:mod:`.frame`), observations, statistics."""

    views: OrthoViews | PinholeViews
    X: np.ndarray
    colors: np.ndarray
    obs: Observations
    frame: Frame
    unit: str
    splits: list[str]
    stats: dict
    masks: list[np.ndarray] | None = None
    timings: dict = field(default_factory=dict)
    dense: np.ndarray | None = None         # [P, 3] the dense start's points (.dense), not in the adjustment
    dense_colors: np.ndarray | None = None  # [P] their grey in [0, 1]
    mask_points: dict | None = None  # the masks' seeds: point indices of the specimen, debris and substrate


def _feature_scale(opts: CalibrationOptions, size: tuple[int, int]) -> float:
    return opts.feature_scale if opts.feature_scale else min(1.0, 1600.0 / max(size))


PREFILTER = 1024  # every pair is first matched on this many strongest keypoints per view


def match_all(feats: list[Features], opts: CalibrationOptions, fscale: float) -> list[PairMatches]:
    """Verified matches of every pair of views (mutual ratio-test matches, RANSAC on the affine F).

    A pair whose :data:`PREFILTER` strongest keypoints give fewer than 8 matches does not overlap enough to
    count and is not matched in full (saves most of the time of series with several arcs)."""
    out = []
    for a, b in combinations(range(len(feats)), 2):
        da, db = feats[a].desc, feats[b].desc
        if max(len(da), len(db)) > 1.5 * PREFILTER and len(match_descriptors(da[:PREFILTER], db[:PREFILTER],
                                                                              opts.ratio)[0]) < 8:
            continue
        ia, ib = match_descriptors(da, db, opts.ratio)
        if len(ia) < opts.min_inliers:
            continue
        inl, normal = ransac_affine_fundamental(feats[a].xy[ia], feats[b].xy[ib], opts.ransac_px / fscale,
                                                seed=a * 1000 + b)
        if inl.sum() >= opts.min_inliers:
            out.append(PairMatches(a, b, ia[inl], ib[inl], normal))
    return out


def _check_connected(series: Series, matches: list[PairMatches]) -> None:
    """DataError naming an image that shares no verified matches with the others."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = len(series)
    edges = np.array([(m.a, m.b) for m in matches]).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(V, V))
    n, label = connected_components(graph, directed=False)
    if n > 1:
        main = np.bincount(label).argmax()
        lone = [i for i in range(V) if label[i] != main]
        raise DataError(f"{series.images[lone[0]].path}: shares no verified matches with "
                        f"{series.images[int(np.nonzero(label == main)[0][0])].path.name} and the other images it "
                        f"should overlap ({len(lone)} of {V} images cut off): the images do not overlap")


def _initial(series: Series, obs: Observations, scale: np.ndarray, opts: CalibrationOptions):
    use_stage = opts.init in ("auto", "stage") and all(t is not None for t in series.tilts)
    if opts.init == "stage" and not use_stage:
        missing = next(im.path for im, t in zip(series.images, series.tilts) if t is None)
        raise DataError(f"{missing}: no stage tilt (metadata or --tilts) for --init stage")
    if use_stage:
        tilts, rots = np.array(series.tilts, float), np.array([r or 0.0 for r in series.rotations])
        views, _, info = init_from_stage(list(tilts), list(rots), scale, obs, flip=opts.flip_depth)
        model = StageModel(info.tilt_sign * tilts, info.rotation_sign * rots, rot_z(np.radians(info.axis_deg)),
                           opts.angle_sigma)
        return views, model, {"method": "stage angles", "source": series.angle_source, **vars(info)}
    views, _, block = init_factorization(obs, len(series), float(scale[0]))
    views.scale[:] = scale
    return views, None, {"method": "affine factorisation", "block": [series.names[b] for b in block]}


def _reject(views: OrthoViews | PinholeViews, X: np.ndarray, obs: Observations, floor_px: float, n_sigma: float = 3.0
            ) -> Observations:
    """``obs`` without the observations off by more than ``max(floor_px, n_sigma robust sigmas)``."""
    err = residuals(views, X, obs)
    thr = max(floor_px, n_sigma * 1.4826 * float(np.median(err)))
    return obs.select(err <= thr)


def _triangulated(views: OrthoViews, obs: Observations) -> np.ndarray:
    return triangulate(views.R, views.t, views.scale, obs.vi, obs.pj, obs.uv, obs.n_points)


def _adjust(views, stage: StageModel | None, obs_all: Observations, opts: CalibrationOptions):
    """BA on the strongest tracks: gross outliers of the initial cameras dropped first, then twice with a
    rejection in between; finally every track triangulated and filtered with the final cameras."""
    obs = strongest_tracks(obs_all, opts.max_ba_tracks)
    obs = _reject(views, _triangulated(views, obs), obs, 3 * opts.reject_px, 5.0)
    info = {}
    for _ in range(2):
        views, X, info = bundle_adjust(views, obs, stage=stage, per_view_scale=opts.per_view_scale,
                                       f_scale=opts.f_scale, max_nfev=100)
        stage = info.pop("stage", None)
        obs = _reject(views, X, obs, opts.reject_px)
    obs_final = obs_all
    for _ in range(2):
        obs_final = _reject(views, _triangulated(views, obs_final), obs_final, opts.reject_px)
    return views, _triangulated(views, obs_final), obs_final, info


def _adjust_perspective(views: OrthoViews, obs_all: Observations, opts: CalibrationOptions,
                        size: tuple[int, int], staged: bool):
    """:func:`_adjust` for pinhole views started from the orthographic ``views`` (:mod:`.perspective`); every
    observation is judged again (the orthographic fit rejected those its missing perspective put off)."""
    from .write import PAPER_FOCAL_PER_PX

    focal = opts.focal_px or PAPER_FOCAL_PER_PX * size[0]
    pv = from_ortho(views, focal, np.array(size, float) / 2)

    def points(v: PinholeViews, o: Observations) -> np.ndarray:  # Gauss-Newton from the orthographic points
        return v.triangulate(o, _triangulated(views, o))

    obs = strongest_tracks(obs_all, opts.max_ba_tracks)
    obs = _reject(pv, points(pv, obs), obs, 3 * opts.reject_px, 5.0)
    info = {}
    for _ in range(2):
        pv, X, info = perspective_adjust(pv, points(pv, obs), obs, estimate_focal=opts.focal_px is None,
                                         sigma_deg=opts.angle_sigma if staged else None, f_scale=opts.f_scale,
                                         max_nfev=100)
        obs = _reject(pv, X, obs, opts.reject_px)
    obs_final = obs_all
    for _ in range(2):
        obs_final = _reject(pv, points(pv, obs_final), obs_final, opts.reject_px)
    info.update(focal_start_px=float(focal), focal_estimated=opts.focal_px is None)
    return pv, points(pv, obs_final), obs_final, info


def _statistics(series: Series, views: OrthoViews | PinholeViews, X: np.ndarray, obs: Observations, n_before: int) -> dict:
    err = residuals(views, X, obs)
    per_view = []
    for v, name in enumerate(series.names):
        e = err[obs.vi == v]
        per_view.append({"view": name, "file": series.images[v].path.name, "observations": len(e),
                         "rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan"),
                         "median_px": float(np.median(e)) if len(e) else float("nan")})
    lengths = obs.track_lengths()
    return {"rms_px": float(np.sqrt(np.mean(err ** 2))), "median_px": float(np.median(err)),
            "observations": len(obs), "rejected_observations": int(n_before - len(obs)),
            "tracks": int(obs.n_points), "mean_track_length": float(lengths.mean()), "per_view": per_view}


def _correspondences(series: Series, opts: CalibrationOptions, log, timings: dict):
    """Features, verified pair matches and tracks of ``series`` (timed into ``timings``)."""
    t0 = time.perf_counter()
    fscale = _feature_scale(opts, series.size)
    feats = [detect_features(series.pixels(i), opts.max_features, fscale, opts.root_sift) for i in range(len(series))]
    timings["features_s"] = time.perf_counter() - t0
    log(f"features: {np.mean([len(f) for f in feats]):.0f} per view at scale {fscale:.3g} "
        f"({timings['features_s']:.1f} s)")
    t1 = time.perf_counter()
    matches = match_all(feats, opts, fscale)
    timings["matching_s"] = time.perf_counter() - t1
    log(f"matching: {len(matches)} verified pairs of {len(series) * (len(series) - 1) // 2} "
        f"({timings['matching_s']:.1f} s)")
    _check_connected(series, matches)
    return feats, matches, build_tracks(matches, [f.xy for f in feats]), fscale


def _refined(series: Series, obs: Observations, views: OrthoViews, opts: CalibrationOptions, log, timings: dict):
    t0 = time.perf_counter()
    obs, info = refine_observations([series.pixels(i) for i in range(len(series))], obs, views.R[:, 2, :],
                                    opts.max_angle, _feature_scale(opts, series.size))
    timings["refine_s"] = time.perf_counter() - t0
    log(f"refinement: {info['refined']} of {info['candidates']} observations moved to their track's reference patch "
        f"(median {info['median_shift_px']:.2f} px); dropped: {info['fit_failed']} whose fit failed, "
        f"{info['beyond_angle']} seen more than {opts.max_angle:g} deg from their reference ({timings['refine_s']:.1f} s)")
    return obs


def calibrate(series: Series, opts: CalibrationOptions | None = None, log=print) -> Calibration:
    """Calibrate ``series`` (module docstring); ``log`` receives progress lines."""
    opts = opts or CalibrationOptions()
    if len(series) < 2:
        raise DataError(f"{series.images[0].path}: a single image; calibration needs two or more views of the "
                        "specimen (three or more without stage tilts)")
    splits = ["test" if opts.holdout and fnmatch.fnmatch(im.path.name, opts.holdout) else "train"
              for im in series.images]
    if "train" not in splits:
        raise DataError(f"--holdout {opts.holdout!r} matches every image; nothing is left to train on")
    timings, t0 = {}, time.perf_counter()
    feats, matches, obs, fscale = _correspondences(series, opts, log, timings)
    p_ref = series.pixel_size_m
    s = 1.0 / (p_ref * 1e6) if p_ref else 1.0  # pixels per micrometre, or per pixel
    scale = np.array([s * (p_ref / p if p and p_ref else 1.0) for p in series.pixel_sizes])
    views, stage, init_info = _initial(series, obs, scale, opts)
    obs = _refined(series, obs, views, opts, log, timings) if opts.refine else obs
    t2 = time.perf_counter()
    views, X, obs_final, ba_info = _adjust(views, stage, obs, opts)
    views, X, frame = world_frame(views, X, stage is not None, opts.flip_depth)
    if opts.camera == "perspective":
        ortho_rms = float(np.sqrt(np.mean(residuals(views, X, obs_final) ** 2)))
        views, X, obs_final, persp = _adjust_perspective(views, obs, opts, series.size, stage is not None)
        ba_info["perspective"] = {**persp, "orthographic_rms_px": ortho_rms}
        frame = refit_substrate(views, X, frame, stage is not None)
        log(f"perspective: focal {views.focal:.0f} px (start {persp['focal_start_px']:.0f}), orthographic RMS "
            f"{ortho_rms:.3f} px")
    timings["adjustment_s"] = time.perf_counter() - t2
    stats = _statistics(series, views, X, obs_final, len(obs))
    stats.update(init=init_info, bundle=ba_info, pairs=len(matches), feature_scale=fscale)
    log(f"bundle adjustment: RMS {stats['rms_px']:.3f} px over {stats['observations']} observations of "
        f"{stats['tracks']} tracks ({timings['adjustment_s']:.1f} s)")
    cal = Calibration(views, X, _point_colors(feats, obs_final), obs_final, frame,
                      "micrometre" if p_ref else "pixel", splits, stats, timings=timings)
    if opts.dense_features and isinstance(views, OrthoViews):
        _densify(series, cal, opts, fscale, log)
    if opts.masks:
        t3 = time.perf_counter()
        cal.masks = _masks(series, cal)
        timings["masks_s"] = time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0
    return cal


def _densify(series: Series, cal: Calibration, opts: CalibrationOptions, fscale: float, log) -> None:
    """The dense start (:mod:`.dense`: more keypoints, then the surface fill) into ``cal.dense`` and
    ``cal.dense_colors``, its figures into the statistics."""
    from .dense import dense_points, surface_fill

    t0 = time.perf_counter()
    pixels = [series.pixels(i) for i in range(len(series))]
    Xk, gk, info = dense_points(pixels, cal.views, opts.dense_features, fscale, ratio=opts.ratio,
                                reject_px=opts.reject_px, max_deg=opts.max_angle, root=opts.root_sift)
    Xf, gf, fill = surface_fill(pixels, cal.views, cal.X, cal.obs, max_deg=opts.max_angle)
    cal.dense, cal.dense_colors = np.concatenate([Xk, Xf]), np.concatenate([gk, gf])
    cal.timings["dense_s"] = time.perf_counter() - t0
    cal.stats["dense"] = {**info, "keypoint_points": info["points"], "points": len(cal.dense), "fill": fill}
    log(f"dense start: {info['points']} points from {info['pairs']} view pairs' keypoints, {fill['kept']} of "
        f"{fill['lifted']} lifted onto the surface ({cal.timings['dense_s']:.1f} s)")


def _point_colors(feats: list[Features], obs: Observations) -> np.ndarray:
    grey = np.concatenate([f.grey for f in feats])
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in feats])])
    g = grey[offsets[obs.vi] + obs.fi]
    return (np.bincount(obs.pj, g, obs.n_points) / np.maximum(obs.track_lengths(), 1)).astype(np.float32)


def _masks(series: Series, cal: Calibration) -> list[np.ndarray]:
    """Masks seeded by the specimen points (above the substrate less the debris, :func:`~.frame.specimen_points`)
    and, as background, the substrate's and the debris' points; the points' split is kept in ``cal.mask_points``
    for the report."""
    sub = cal.frame.substrate
    main = specimen_points(sub, cal.frame.height, cal.X)
    spec, debris = np.flatnonzero(main), np.flatnonzero(above_substrate(sub, cal.frame.height, len(cal.X)) & ~main)
    other = np.concatenate([np.flatnonzero(sub) if sub is not None else np.zeros(0, int), debris])
    all_v = np.arange(len(series))
    uv = lambda P: [cal.views.project(P, Observations(np.full(len(P), v), np.arange(len(P)), None, None, len(P)))
                    for v in all_v]
    cal.mask_points = {"specimen": spec, "debris": debris, "substrate": np.flatnonzero(sub) if sub is not None
                       else np.zeros(0, int)}
    cal.stats["masks"] = {"specimen_points": len(spec), "debris_points": len(debris)}
    return specimen_masks([to_u8_stretched(series.pixels(i)) for i in all_v], uv(cal.X[spec]),
                          uv(cal.X[other]) if len(other) else None)
