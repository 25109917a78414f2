"""The calibration report: ``report/calibration.json``, ``report/report.md`` and three images.

* ``residuals.png``: left, every observation's reprojection error as a line from where the feature was
  found, magnified (``x RESIDUAL_GAIN``), over the image frame; right, each view's RMS error as a bar;
* ``overlay_<view>.png`` for two views (the first and the middle one): the features found (green circles),
  where the calibrated cameras put their points (red dots) and the fitted tilt axis through the centre
  (yellow, the principal axis; cyan, a second arc's axis);
* ``masks_<view>.png`` for the same views, where the calibration made masks: the specimen mask (green tint and
  outline) with the points that seeded it: specimen (green), debris (red) and substrate (blue) points, the last two
  as background (:mod:`.masks`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..files import write_json_atomic, write_text_atomic
from ..sem.series import Series
from .features import to_u8_stretched
from .frame import tilt_axes

__all__ = ["RESIDUAL_GAIN", "overlay", "residual_image", "write_report"]

RESIDUAL_GAIN = 25.0
PANEL = 900


def residual_image(size: tuple[int, int], uv: np.ndarray, delta: np.ndarray, rms: list[float],
                   names: list[str]) -> np.ndarray:
    """``[H, W, 3]`` uint8 BGR (module docstring); ``uv, delta [n, 2]`` observations and their errors."""
    import cv2

    w, h = size
    f = PANEL / max(w, h)
    W, H = round(w * f), round(h * f)
    bar_w = 360
    img = np.full((max(H, 24 * len(names) + 40), W + bar_w, 3), 255, np.uint8)
    cv2.rectangle(img, (0, 0), (W - 1, H - 1), (120, 120, 120), 1)
    a = np.round(uv * f).astype(int)
    b = np.round((uv + RESIDUAL_GAIN * delta) * f).astype(int)
    big = np.linalg.norm(delta, axis=1) > 1.0
    for p, q, bad in zip(a, b, big):
        cv2.line(img, tuple(map(int, p)), tuple(map(int, q)), (0, 0, 230) if bad else (200, 90, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"reprojection errors x{RESIDUAL_GAIN:g} (red: > 1 px)", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                (0, 0, 0), 1, cv2.LINE_AA)
    top = max(rms + [1e-9])
    for i, (name, r) in enumerate(zip(names, rms)):
        y = 30 + 24 * i
        length = int(150 * r / top) if np.isfinite(r) else 0
        cv2.rectangle(img, (W + 150, y), (W + 150 + length, y + 16), (200, 90, 0), -1)
        cv2.putText(img, f"{name[:16]}", (W + 6, y + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, f"{r:.2f}", (W + 156 + length, y + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1,
                    cv2.LINE_AA)
    cv2.putText(img, "RMS px per view", (W + 150, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def overlay(img8: np.ndarray, found: np.ndarray, projected: np.ndarray, axes_2d: list[np.ndarray]) -> np.ndarray:
    """``[H, W, 3]`` BGR: ``img8 [H, W]`` with features ``found`` and reprojections ``projected [n, 2]``,
    and lines through the centre along ``axes_2d`` (unit image directions)."""
    import cv2

    H, W = img8.shape
    f = min(1.0, 1400 / max(H, W))
    img = cv2.cvtColor(cv2.resize(img8, (round(W * f), round(H * f)), interpolation=cv2.INTER_AREA),
                       cv2.COLOR_GRAY2BGR)
    for p, q in zip(np.round(found * f).astype(int), np.round(projected * f).astype(int)):
        cv2.circle(img, tuple(map(int, p)), 4, (0, 200, 0), 1, cv2.LINE_AA)
        cv2.circle(img, tuple(map(int, q)), 1, (0, 0, 255), -1)
    c = np.array([img.shape[1] / 2, img.shape[0] / 2])
    for d, colour in zip(axes_2d, [(0, 220, 255), (255, 220, 0)]):
        L = 0.45 * max(img.shape[:2])
        p, q = np.round(c - L * d).astype(int), np.round(c + L * d).astype(int)
        cv2.line(img, tuple(map(int, p)), tuple(map(int, q)), colour, 2, cv2.LINE_AA)
    return img


def _mask_image(series: Series, cal, v: int) -> np.ndarray:
    """View ``v``'s mask and its seed points (:func:`~.masks.mask_overlay`)."""
    from .masks import mask_overlay
    from .tracks import Observations

    def uv(idx):
        P = cal.X[idx]
        return cal.views.project(P, Observations(np.full(len(P), v), np.arange(len(P)), None, None, len(P)))

    pts = cal.mask_points
    return mask_overlay(to_u8_stretched(series.pixels(v)), cal.masks[v], uv(pts["specimen"]), uv(pts["debris"]),
                        uv(pts["substrate"]))


def _camera_line(cal) -> str:
    persp = cal.stats.get("bundle", {}).get("perspective")
    if persp is None:
        return "Camera: orthographic (parallel projection)."
    how = f"estimated, from a start of {persp['focal_start_px']:.0f} px" if persp["focal_estimated"] else "given"
    return (f"Camera: perspective (pinhole), focal length {persp['focal_px']:.0f} px ({how}); the orthographic "
            f"adjustment it started from: RMS {persp['orthographic_rms_px']:.3f} px.")


def _table(per_view: list[dict], splits: list[str], tilts) -> str:
    lines = ["| view | split | stage tilt | observations | RMS px | median px |", "|---|---|---|---|---|---|"]
    for row, split, tilt in zip(per_view, splits, tilts):
        lines.append(f"| {row['view']} | {split} | {'-' if tilt is None else f'{tilt:.2f}'} | {row['observations']} | "
                     f"{row['rms_px']:.3f} | {row['median_px']:.3f} |")
    return "\n".join(lines)


def write_report(folder: Path, series: Series, cal, options: dict, command: str) -> None:
    """Write ``folder/report/`` for calibration ``cal`` of ``series`` (module docstring)."""
    import cv2

    out = folder / "report"
    out.mkdir(parents=True, exist_ok=True)
    axes = tilt_axes(cal.views)
    proj = cal.views.project(cal.X, cal.obs)
    delta = proj - cal.obs.uv
    stats = cal.stats
    rms = [r["rms_px"] for r in stats["per_view"]]
    cv2.imwrite(str(out / "residuals.png"), residual_image(series.size, cal.obs.uv, delta, rms, series.names))
    picks = sorted({0, len(series) // 2})
    for v in picks:
        sel = cal.obs.vi == v
        dirs = [np.array((cal.views.R[v] @ np.array(a["axis"]))[:2]) for a in axes[:2]]
        dirs = [d / np.linalg.norm(d) for d in dirs if np.linalg.norm(d) > 1e-6]
        img = overlay(to_u8_stretched(series.pixels(v)), cal.obs.uv[sel], proj[sel], dirs)
        cv2.imwrite(str(out / f"overlay_{series.names[v].replace('/', '_')}.png"), img)
        if cal.masks is not None and cal.mask_points is not None:
            cv2.imwrite(str(out / f"masks_{series.names[v].replace('/', '_')}.png"), _mask_image(series, cal, v))
    record = {"command": command, "options": options, "unit": cal.unit, "crop": vars(series.crop),
              "angle_source": series.angle_source, "frame": {"mirrored": cal.frame.mirrored, "notes": cal.frame.notes},
              "tilt_axes": axes, "timings_s": cal.timings, **stats}
    write_json_atomic(out / "calibration.json", record)
    axis_lines = [f"- axis {i + 1}: world {np.round(a['axis'], 3).tolist()}, {a['image_angle_deg']:.1f} deg from the "
                  f"image x axis, {a['out_of_plane_deg']:.1f} deg out of the image plane, {a['pairs']} view pairs, "
                  f"mean step {a['mean_step_deg']:.2f} deg" for i, a in enumerate(axes)]
    kinds = ["overlay", *(["masks"] if cal.masks is not None and cal.mask_points else [])]
    text = [f"# Calibration of {series.folder.name}", "", f"`{command}`", "",
            (f"RMS reprojection error {stats['rms_px']:.3f} px (median {stats['median_px']:.3f} px) over "
            f"{stats['observations']} observations of {stats['tracks']} tracks "
            f"(mean length {stats['mean_track_length']:.1f}); {stats['rejected_observations']} observations rejected "
            f"as outliers; {stats['pairs']} verified image pairs."), "",
            f"Initialisation: {stats['init']['method']}. World unit: one {cal.unit}. Crop: {series.crop.describe()}.",
            *(["", (f"Dense start: {stats['dense']['points']} more points for training (points3d.ply), triangulated "
                   f"with these cameras from {stats['dense']['pairs']} view pairs of "
                   f"{stats['dense']['features_per_view']:.0f} keypoints per view (not in the adjustment).")]
              if stats.get("dense", {}).get("points") else []),
            "", _camera_line(cal),
            "", "Tilt axes (between consecutive views):", *axis_lines, "", *[f"- {n}" for n in cal.frame.notes], "",
            _table(stats["per_view"], cal.splits, series.tilts),
            *(["", (f"Masks: seeded by {stats['masks']['specimen_points']} specimen points; "
                    f"{stats['masks']['debris_points']} points above the substrate apart from the specimen (debris) "
                    "and the substrate's points are background (`masks_<view>.png`: specimen green, debris red, "
                    "substrate blue).")] if "masks" in stats else []),
            "", "Images: `residuals.png`, " + ", ".join(
                f"`{kind}_{series.names[v].replace('/', '_')}.png`" for v in picks for kind in kinds)]
    write_text_atomic(out / "report.md", "\n".join(text) + "\n")
