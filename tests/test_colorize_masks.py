"""Automatic specimen masks: Otsu + morphology on a synthetic disc; GrabCut; sources."""
import numpy as np
import pytest
import torch

from arcsem.colorize.masks import grabcut_mask, otsu_mask, specimen_masks
from arcsem.errors import ConfigError


def _disc(h=96, w=128, r=30, seed=0):
    yy, xx = np.mgrid[:h, :w]
    cx, cy = w * 0.55, h * 0.47
    disc = (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r
    rng = np.random.default_rng(seed)
    img = np.where(disc, 0.7, 0.15) + rng.normal(0, 0.05, (h, w))
    img[(xx - cx) ** 2 + (yy - cy) ** 2 <= (r / 4) ** 2] = 0.1  # a dark pit inside (a hole to fill)
    img[5:8, 5:8] = 0.9  # a bright speck outside (a component to drop)
    return np.clip(img, 0, 1).astype(np.float32), disc


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_otsu_mask_matches_disc():
    img, disc = _disc()
    m = otsu_mask(img)
    assert m.dtype == bool and _iou(m, disc) > 0.95
    assert m[int(96 * 0.47), int(128 * 0.55)] and not m[6, 6]


def test_grabcut_mask_matches_disc():
    img, disc = _disc()
    assert _iou(grabcut_mask(np.repeat(img[..., None], 3, -1)), disc) > 0.9


def test_specimen_mask_sources():
    img, _ = _disc(48, 64, 15)

    class S:
        images = torch.from_numpy(np.repeat(img[None, ..., None], 3, -1))
        masks = None
        names = ("a",)

        class cameras:
            height, width = 48, 64

        def __len__(self):
            return 1

    s = S()
    assert specimen_masks(s, "auto").shape == (1, 48, 64)
    assert specimen_masks(s, "none").all()
    with pytest.raises(Exception, match="no masks"):
        specimen_masks(s, "dataset")
    with pytest.raises(ConfigError, match="segment_anything|checkpoint"):
        specimen_masks(s, "sam")
    with pytest.raises(ConfigError, match="unknown source"):
        specimen_masks(s, "magic")
