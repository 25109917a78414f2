"""SIFT / RootSIFT features of SEM images, optionally computed on a downscaled copy.

Keypoints are returned in the full-resolution (cropped) image in arcsem's pixel convention (centre of
pixel ``(i, j)`` at ``(i + 0.5, j + 0.5)``): a keypoint at OpenCV position ``x`` of a copy downscaled by
``f`` lies at ``(x + 0.5) / f``. RootSIFT (Arandjelovic & Zisserman 2012): L1-normalise, square root; the
vectors then have unit L2 norm and their dot product is the Hellinger kernel.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Features", "detect_features", "to_u8_stretched"]


@dataclass
class Features:
    """``xy [K, 2]`` float64 keypoints (full-res pixels), ``desc [K, 128]`` float32 unit-norm, ``grey [K]``
    float32 image values at the keypoints (for point colours); strongest keypoints first."""

    xy: np.ndarray
    desc: np.ndarray
    grey: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


def to_u8_stretched(pixels: np.ndarray) -> np.ndarray:
    """uint8 as is; uint16 stretched between its 0.1 and 99.9 percentiles to ``0..255``."""
    if pixels.dtype == np.uint8:
        return pixels
    lo, hi = np.percentile(pixels[::4, ::4], (0.1, 99.9))
    return np.clip((pixels.astype(np.float32) - lo) * (255.0 / max(hi - lo, 1.0)), 0, 255).astype(np.uint8)


def detect_features(pixels: np.ndarray, max_features: int = 4000, scale: float = 1.0, root: bool = True,
                    contrast: float = 0.02) -> Features:
    """SIFT features of ``pixels [H, W]`` (uint8/uint16) computed at ``scale`` (<= 1) of its size.

    ``max_features``: the strongest keypoints kept; ``contrast``: OpenCV's ``contrastThreshold`` (its default
    0.04 finds few keypoints on low-contrast SEM surfaces); ``root``: RootSIFT descriptors.
    """
    import cv2

    img = to_u8_stretched(pixels)
    small = img if scale >= 1.0 else cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    f = small.shape[1] / img.shape[1]
    sift = cv2.SIFT_create(nfeatures=max_features, contrastThreshold=contrast)
    kps, desc = sift.detectAndCompute(small, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32), np.zeros(0, np.float32))
    order = np.argsort([-k.response for k in kps], kind="stable")  # strongest first (the matcher's pre-filter)
    xy = (np.array([kps[i].pt for i in order], dtype=np.float64) + 0.5) / f
    desc = desc[order].astype(np.float32)
    if root:
        desc = np.sqrt(desc / np.maximum(desc.sum(1, keepdims=True), 1e-12))
    else:
        desc = desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    ij = np.clip(np.floor(xy).astype(int), 0, [img.shape[1] - 1, img.shape[0] - 1])
    grey = img[ij[:, 1], ij[:, 0]].astype(np.float32) / 255.0
    # drop duplicates: OpenCV returns one keypoint per orientation at the same position
    _, first = np.unique(np.round(xy * 8).astype(np.int64), axis=0, return_index=True)
    first = np.sort(first)
    return Features(xy[first], np.ascontiguousarray(desc[first]), grey[first])
