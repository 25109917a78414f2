"""Initial cameras from stage angles: where the tilt axis lies in the image and how the rotation turns.

Files do not say where the tilt axis appears in the image (scan rotation, detector mounting) nor the sense
of the stage rotation. Each hypothesis (rotation sign, axis angle in the image: 12 steps of 15 degrees over
a half turn, then 2.5-degree steps around the best) gives rotations by :func:`~.geometry.stage_rotation`; the
points and translations are then a linear least-squares problem
(:func:`~.geometry.solve_points_translations`), and the hypothesis with the smallest median reprojection
error wins. The other half turn of axis angles is not tried: turning the axis by 180 degrees reproduces
every pixel with the relief mirrored in depth (the Necker reversal of parallel projection), so it cannot be
told from the images; arcsem's convention (:mod:`.geometry`: positive tilt turns the stage about the axis
nearest the image's +x direction, the stage's y going away from the beam at its top) decides, and
``--flip-depth`` takes the mirror when a microscope tilts the other way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bundle import OrthoViews
from .geometry import solve_points_translations, stage_rotation
from .tracks import Observations

__all__ = ["StageInit", "init_from_stage", "strongest_tracks"]


@dataclass
class StageInit:
    """The chosen convention: ``tilt_sign`` (-1 with ``flip``), ``rotation_sign``, ``axis_deg`` (tilt axis from
    the image x axis), its median reprojection error ``score`` (pixels) and that of the best hypothesis with
    another rotation sign or an axis more than 20 degrees away (``runner_up``)."""

    tilt_sign: float
    rotation_sign: float
    axis_deg: float
    score: float
    runner_up: float


def strongest_tracks(obs: Observations, k: int) -> Observations:
    """The ``k`` tracks seen by the most views (all if fewer)."""
    lengths = obs.track_lengths()
    if obs.n_points <= k:
        return obs
    keep_tracks = np.zeros(obs.n_points, bool)
    keep_tracks[np.argsort(-lengths, kind="stable")[:k]] = True
    return obs.select(keep_tracks[obs.pj])


def _score(R: np.ndarray, scale: np.ndarray, obs: Observations) -> float:
    X, t = solve_points_translations(R, scale, obs.vi, obs.pj, obs.uv, obs.n_points)
    pred = np.einsum("nij,nj->ni", R[obs.vi, :2, :], X[obs.pj]) * scale[obs.vi, None] + t[obs.vi]
    return float(np.median(np.linalg.norm(pred - obs.uv, axis=1)))


def _rotations(tilts, rots, ts: float, rs: float, axis: float) -> np.ndarray:
    return np.stack([stage_rotation(ts * t, rs * r, axis) for t, r in zip(tilts, rots)])


def init_from_stage(tilts: list[float], rots: list[float], scale: np.ndarray, obs: Observations,
                    max_tracks: int = 1500, flip: bool = False) -> tuple[OrthoViews, np.ndarray, StageInit]:
    """Initial views and points ``X [N, 3]`` for all tracks of ``obs`` from stage angles (module docstring);
    ``flip``: the microscope tilts the other way (every tilt negated: the mirrored relief)."""
    sub = strongest_tracks(obs, max_tracks)
    ts = -1.0 if flip else 1.0
    signs = (1.0,) if np.ptp(rots) < 1e-6 else (1.0, -1.0)  # a constant rotation: its sense does not matter
    scored = [(_score(_rotations(tilts, rots, ts, rs, ax), scale, sub), rs, ax)
              for rs in signs for ax in np.arange(-90.0, 90.0, 15.0)]
    best = min(scored)
    scored += [(_score(_rotations(tilts, rots, ts, best[1], ax), scale, sub), best[1], ax)
               for ax in best[2] + np.arange(-7.5, 7.6, 2.5) if ax != best[2]]
    score, rs, ax = min(scored)
    others = [s[0] for s in scored if abs(s[2] - ax) > 20 or s[1] != rs]
    R = _rotations(tilts, rots, ts, rs, ax)
    X, t = solve_points_translations(R, scale, obs.vi, obs.pj, obs.uv, obs.n_points)
    info = StageInit(ts, rs, float(ax), score, float(min(others)) if others else float("nan"))
    return OrthoViews(R, t, scale.copy()), X, info
