"""The second synthetic specimen (a diatom frustule) and the grain scene left as it was."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from arcsem.errors import ConfigError
from arcsem.synthetic import SceneParams, generate_scene
from arcsem.synthetic.cache import scene_key
from arcsem.synthetic.diatom import _capsule, _pits, _sector, _spines, diatom_parts, make_diatom


def test_grain_cache_key_and_records_unchanged_by_the_specimen_option():
    # the key of the built-in scene before the `specimen` option existed (main at 9d221f6): its cache folder,
    # stage-1 keys and transforms.json stay valid
    assert scene_key(SceneParams()) == "fc9ff3ae9003531d"
    assert scene_key(SceneParams(specimen="diatom")) != scene_key(SceneParams())
    with pytest.raises(ConfigError, match="unknown specimen 'sponge'"):
        generate_scene("/nonexistent/never-written", specimen="sponge", width=16, height=16)


def test_sector_repetition_is_exact_near_the_surface():
    d = make_diatom(0)
    g = torch.Generator().manual_seed(0)
    p = (torch.rand(20000, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([2.2, 2.2, 1.6],
                                                                                      dtype=torch.float64)
    # spines: the repeated evaluation equals the minimum over every spine
    h = d.half_height
    pts = torch.tensor([[d.radius - 0.08, 0, h - 0.03], [d.radius - 0.03, 0, h + 0.30],
                        [d.radius - 0.28, 0, h + 0.45]], dtype=torch.float64)
    dense = torch.full((len(p),), float("inf"), dtype=torch.float64)
    for k in range(d.n_spines):
        a = 2 * torch.pi * k / d.n_spines + d.phase + torch.pi / d.n_spines
        c, s = np.cos(a), np.sin(a)
        rot = torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64)
        q = p @ rot  # into spine k's frame
        dense = torch.minimum(dense, torch.minimum(_capsule(q, pts[0], pts[1], d.spine_r),
                                                   _capsule(q, pts[1], pts[2], 0.8 * d.spine_r)))
    near = dense < 0.1
    torch.testing.assert_close(_spines(d, p)[near], dense[near])
    # pits lie inside their sectors: the pit distance is never below the distance to the sector's border
    q, _ = _sector(p, d.n_rows, d.phase)
    assert bool((_pits(d, p) < 0).any())
    inside = _pits(d, p) < 0
    border = q[:, 0].abs() * np.sin(np.pi / d.n_rows) - q[:, 1].abs() * np.cos(np.pi / d.n_rows)
    assert bool((border[inside] > 0).all())


def test_diatom_scene_renders_with_a_dish_pits_and_spines(tmp_path):
    path = generate_scene(tmp_path / "d", specimen="diatom", width=48, height=32, n_horizontal=3, n_vertical=3,
                          supersample=1)
    meta = json.loads(path.read_text())
    assert meta["synthetic"]["specimen"] == "diatom" and "diatom" in (path.parent / "README.txt").read_text()
    top = next(f for f in meta["frames"] if f["split"] == "train" and f["arc"] == "v" and f["elevation"] > 80)
    mask = np.asarray(Image.open(path.parent / top["mask_path"])) > 0
    color = np.asarray(Image.open(path.parent / top["color_path"])).astype(float) / 255
    assert 0.2 < mask.mean() < 0.8
    # the top view shows the orange spines and the blue/teal dish (blue > red on the dish)
    orange = (color[..., 0] > 0.5) & (color[..., 2] < 0.2) & mask
    bluish = (color[..., 2] > color[..., 0] + 0.1) & mask
    assert orange.sum() > 5 and bluish.sum() > 20
    d = make_diatom(0)
    parts = diatom_parts(d, torch.tensor([[0.0, 0.0, d.half_height - d.dish_depth]], dtype=torch.float64))
    assert abs(float(parts["sdf"][0])) < 1e-6  # the floor of the dish is a surface point (a concavity)
