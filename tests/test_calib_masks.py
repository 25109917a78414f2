"""Calibration masks (arcsem.calib.masks): debris apart from the specimen, and masks that leave it out."""
from __future__ import annotations

import numpy as np
import pytest

from arcsem.calib import masks as M


def _blob(rng, centre, radius, n):
    d = rng.normal(size=(n, 3))
    return np.asarray(centre) + radius * d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.3, 1, (n, 1))


def test_split_debris_keeps_the_specimen_and_drops_small_parts_apart_from_it():
    """A grain of 400 points and two particles of 15 points on the substrate 3 units away: the particles are
    debris. A second body as large as half the grain is specimen (a specimen of two parts)."""
    rng = np.random.default_rng(0)
    grain = _blob(rng, [0, 0, 1], 1.0, 400)
    debris = np.concatenate([_blob(rng, [3.5, 0, 0.1], 0.08, 15), _blob(rng, [-3, 2, 0.1], 0.08, 15)])
    main = M.split_debris(np.concatenate([grain, debris]))
    assert main[:400].all() and not main[400:].any()
    second = _blob(rng, [0, 4, 1], 0.7, 200)
    both = M.split_debris(np.concatenate([grain, second, debris]))
    assert both[:600].all() and not both[600:].any()
    assert M.split_debris(debris[:5]).all()  # too few points to tell: all specimen


def test_split_debris_depends_on_the_share_rule(monkeypatch):
    """Without the share rule (every part kept) the particles would seed the specimen mask."""
    rng = np.random.default_rng(1)
    X = np.concatenate([_blob(rng, [0, 0, 1], 1.0, 300), _blob(rng, [3, 0, 0.1], 0.08, 12)])
    import arcsem.calib.frame as F

    monkeypatch.setattr(F, "DEBRIS_SHARE", 0.0)
    assert M.split_debris(X).all()


def _image_with_particle():
    """A 160x120 dark substrate with a bright grain (radius 30 at (60, 60)) and a bright particle (radius 8 at
    (130, 30)); points sampled over each (the masks' seeds are discs around them)."""
    import cv2

    img = np.full((120, 160), 40, np.uint8)
    cv2.circle(img, (60, 60), 30, 200, -1)
    cv2.circle(img, (130, 30), 8, 200, -1)
    rng = np.random.default_rng(2)
    a, r = rng.uniform(0, 2 * np.pi, 600), 28 * np.sqrt(rng.uniform(0, 1, 600))
    grain = np.stack([60 + r * np.cos(a), 60 + r * np.sin(a)], 1)
    particle = np.array([[130, 30], [133, 31], [127, 29], [130, 34], [130, 26]], float)
    substrate = np.array([[10, 110], [150, 110], [10, 10], [100, 100]], float)
    return img, grain, particle, substrate


@pytest.mark.parametrize("particle_as", ["background", "specimen"])
def test_masks_leave_out_a_particle_seeded_as_background(particle_as):
    img, grain, particle, substrate = _image_with_particle()
    if particle_as == "background":
        mask = M.specimen_masks([img], [grain], [np.concatenate([substrate, particle])])[0]
    else:  # what the masks were before debris was told apart: the particle's points seed the specimen
        mask = M.specimen_masks([img], [np.concatenate([grain, particle])], [substrate])[0]
    assert mask[60, 60] and mask[60, 85] and not mask[110, 10]
    assert mask[30, 130] == (particle_as == "specimen")


def test_mask_overlay_draws_the_mask_and_the_seeds():
    img, grain, particle, substrate = _image_with_particle()
    mask = M.specimen_masks([img], [grain], [np.concatenate([substrate, particle])])[0]
    out = M.mask_overlay(img, mask, grain, particle, substrate)
    assert out.shape == (120, 160, 3)
    b, g, r = out[30, 130].astype(int)  # a debris point: red
    assert r > 200 and g < 50 and b < 50
    inside = out[60, 45].astype(int)  # inside the mask, off the points: tinted green
    assert inside[1] > inside[0] and inside[1] > inside[2]
