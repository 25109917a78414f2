"""Automatic specimen masks, seeded by the sparse points.

Each view is segmented on a copy at most :data:`WORK_SIZE` pixels wide by OpenCV's marker watershed over
the (lightly smoothed) image: discs around the projections of the specimen points are foreground seeds,
discs around the substrate points (:mod:`.frame`) and the pixels farther than :data:`FAR` of the image size
from every specimen point are background seeds. The regions meet on
the strongest edges between the seeds (SEM silhouettes are bright edges). The result is cleaned by
morphology (closing, opening, holes filled) and keeps only the connected parts that hold specimen seeds.
Files given with ``--masks`` replace these.
"""
from __future__ import annotations

import numpy as np

__all__ = ["specimen_masks"]

WORK_SIZE = 256
FAR = 0.01


def _discs(shape, pts: np.ndarray, radius: int) -> np.ndarray:
    import cv2

    out = np.zeros(shape, np.uint8)
    for x, y in np.round(pts).astype(int):
        if 0 <= x < shape[1] and 0 <= y < shape[0]:
            cv2.circle(out, (int(x), int(y)), radius, 1, -1)
    return out.astype(bool)


def _clean(mask: np.ndarray, seeds: np.ndarray, k: int) -> np.ndarray:
    """Close, open, fill holes; keep the components that contain seed pixels (``seeds`` bool)."""
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
    m = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, kernel)
    flood = np.pad(1 - m, 1, constant_values=1).astype(np.uint8)
    cv2.floodFill(flood, None, (0, 0), 2)
    m = (m | (flood[1:-1, 1:-1] != 2)).astype(np.uint8)
    _n, labels = cv2.connectedComponents(m)
    keep = np.unique(labels[seeds & (labels > 0)])
    return np.isin(labels, keep) & (m > 0)


def _watershed(img: np.ndarray, fg: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Specimen pixels: OpenCV's watershed from the ``fg`` / ``bg`` seed pixels over ``img`` (uint8)."""
    import cv2

    markers = np.zeros(img.shape, np.int32)
    markers[bg] = 1
    markers[fg] = 2
    cv2.watershed(cv2.cvtColor(cv2.GaussianBlur(img, (0, 0), 1.0), cv2.COLOR_GRAY2BGR), markers)
    return markers == 2


def specimen_masks(images: list[np.ndarray], specimen_uv: list[np.ndarray], substrate_uv: list[np.ndarray] | None
                   ) -> list[np.ndarray]:
    """``[H, W]`` bool masks of ``images`` (uint8 ``[H, W]``) from the projected specimen points
    ``specimen_uv[v] [k, 2]`` and substrate points (None without a substrate); module docstring."""
    import cv2

    out = []
    for img, spec, sub in zip(images, specimen_uv, substrate_uv or [None] * len(images)):
        H, W = img.shape
        f = min(1.0, WORK_SIZE / max(H, W))
        small = cv2.resize(img, (max(1, round(W * f)), max(1, round(H * f))), interpolation=cv2.INTER_AREA)
        r = max(2, round(0.012 * max(small.shape)))
        fg = _discs(small.shape, spec * f, r)
        far = cv2.distanceTransform((~fg).astype(np.uint8), cv2.DIST_L2, 3)
        bg = far > FAR * max(small.shape)          # far from every specimen point: background
        if sub is not None and len(sub):
            bg |= _discs(small.shape, sub * f, r) & ~fg
        raw = _watershed(small, fg, bg) if fg.any() and bg.any() else fg
        mask = _clean(raw, fg, r)
        out.append(cv2.resize(mask.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool))
    return out
