"""Automatic specimen masks, seeded by the sparse points.

The points clearly above the substrate are first split into the specimen and debris (:func:`split_debris`, in
:mod:`.frame`, where the specimen's box and the origin take the same split): the
connected parts of their 3-D neighbour graph, the largest one the specimen, any part with under
:data:`DEBRIS_SHARE` of its points debris. Debris lies on the substrate like the specimen but is not what the
user imaged; counted in, it made the masks, the masked metrics and the mesh include it.

Each view is segmented on a copy at most :data:`WORK_SIZE` pixels wide by OpenCV's marker watershed over
the (lightly smoothed) image: discs around the projections of the specimen points are foreground seeds,
discs around the substrate and debris points (:mod:`.frame`) and the pixels farther than :data:`FAR` of the image size
from every specimen point are background seeds. The regions meet on
the strongest edges between the seeds (SEM silhouettes are bright edges). The result is cleaned by
morphology (closing, opening, holes filled) and keeps only the connected parts that hold specimen seeds.
Files given with ``--masks`` replace these.
"""
from __future__ import annotations

import numpy as np

from .frame import DEBRIS_SHARE, split_debris

__all__ = ["DEBRIS_SHARE", "mask_overlay", "specimen_masks", "split_debris"]

WORK_SIZE = 256
FAR = 0.01
def mask_overlay(img8: np.ndarray, mask: np.ndarray, specimen_uv: np.ndarray, debris_uv: np.ndarray,
                 substrate_uv: np.ndarray | None) -> np.ndarray:
    """``[h, w, 3]`` BGR, at most 1400 px wide: ``img8 [H, W]`` with the mask tinted green and its outline, the
    specimen points (green), debris points (red) and substrate points (blue) as dots."""
    import cv2

    H, W = img8.shape
    f = min(1.0, 1400 / max(H, W))
    size = (round(W * f), round(H * f))
    img = cv2.cvtColor(cv2.resize(img8, size, interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
    m = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    img[m > 0] = (0.6 * img[m > 0] + 0.4 * np.array([60, 200, 60])).astype(np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, (0, 255, 0), 1, cv2.LINE_AA)
    for pts, colour in ((specimen_uv, (0, 200, 0)), (debris_uv, (0, 0, 255)),
                        (substrate_uv if substrate_uv is not None else np.zeros((0, 2)), (255, 120, 0))):
        for x, y in np.round(np.asarray(pts) * f).astype(int):
            cv2.circle(img, (int(x), int(y)), 2, colour, -1)
    return img


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
    ``specimen_uv[v] [k, 2]`` and the points that are not the specimen (substrate and debris; None without any);
    module docstring."""
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
