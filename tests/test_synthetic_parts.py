"""The third synthetic specimen: colour is a function of the part (body, spines, pores, debris, substrate)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

from arcsem.data import check_dataset_config
from arcsem.errors import ConfigError
from arcsem.synthetic import SceneParams, generate_scene
from arcsem.synthetic.cache import scene_key
from arcsem.synthetic.cameras import arc_cameras, arc_views
from arcsem.synthetic.parts import PALETTE, PART_NAMES, make_parts, parts_albedo, parts_label, parts_sdf
from arcsem.synthetic.render import RenderConfig, render_views


def _surface_points(g) -> dict[str, torch.Tensor]:
    """One surface point ``[1, 3]`` of each part, built from the specimen's own parameters."""
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64)).reshape(1, 3)
    tip, base = g.spine_tip[0], g.spine_base[0]
    axis = (tip - base) / np.linalg.norm(tip - base)
    c = g.pore_centres[0]
    return {"spine": t(tip + g.spine_r * axis), "pore": t(c - g.pore_r * c / np.linalg.norm(c)),
            "debris": t(g.debris[0, :3] + [0, 0, g.debris[0, 3]]), "body": t([0.0, 0.0, -g.body_radii[2]])}


def test_each_part_has_its_own_uniform_colour():
    g = make_parts(0)
    pts = _surface_points(g)
    for name, p in pts.items():
        assert abs(float(parts_sdf(g, p)["sdf"][0])) < 1e-6, name  # a point of the surface
        assert PART_NAMES[int(parts_label(g, p)[0])] == name
        torch.testing.assert_close(parts_albedo(g, p)[0], torch.tensor(PALETTE[name], dtype=torch.float64))
    # the body has one colour at every latitude (bottom pole and a bare point on the equator)
    dirs = torch.tensor([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 64)], dtype=torch.float64)
    eq = dirs * torch.tensor(g.body_radii, dtype=torch.float64)
    body = eq[parts_label(g, eq) == 0]
    assert len(body) > 10
    assert torch.equal(parts_albedo(g, body), parts_albedo(g, pts["body"]).expand(len(body), 3))
    hues = {tuple(np.round(np.asarray(c) / max(c), 2)) for c in PALETTE.values()}
    assert len(hues) == len(PALETTE)  # five distinct hues


def _one_view(g, cfg=None):
    views = [v for v in arc_views(3, 3) if v.name == "v_01"]
    cams, _ = arc_cameras(views, 72, 48)
    return render_views(g, cams, cfg or RenderConfig(supersample=1))[0]


def _direction(rgb: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.normalize(rgb.double(), dim=-1)


def test_rendered_colour_follows_the_part_and_the_grey_does_not_reveal_it():
    g = make_parts(0)
    r = _one_view(g)
    label = parts_label(g, r.points.double())
    col = r.color.reshape(-1, 3)[r.mask.reshape(-1)]
    for name in ("body", "spine", "debris"):  # seen from this view (a pore may hide behind a spine)
        k = PART_NAMES.index(name)
        here = (label == k) & (col.amax(-1) < 0.999)  # not clipped at white
        assert here.sum() > 3, name
        want = _direction(torch.tensor(PALETTE[name]))
        assert float((_direction(col[here]) @ want).min()) > 0.999, name  # colour = albedo x grey
    sub = (~r.mask) & (r.grey > r.grey.min() + 0.05)  # the lit substrate
    assert float((_direction(r.color[sub]) @ _direction(torch.tensor(PALETTE["substrate"]))).min()) > 0.999
    # the SEM grey is geometry only: another palette gives the same grey and other colours
    swapped = dict(zip(PALETTE, list(PALETTE.values())[::-1]))
    r2 = _one_view(replace(g, palette=swapped))
    assert torch.equal(r2.grey, r.grey) and not torch.allclose(r2.color, r.color)


def test_parts_scene_generates_at_the_demos_size(tmp_path):
    path = generate_scene(tmp_path / "p", specimen="parts", width=288, height=192, n_horizontal=3, n_vertical=2,
                          supersample=1)
    meta = json.loads(path.read_text())
    assert meta["synthetic"]["specimen"] == "parts" and (meta["w"], meta["h"]) == (288, 192)
    assert "coloured by part" in (path.parent / "README.txt").read_text()
    f = meta["frames"][0]
    color = np.asarray(Image.open(path.parent / f["color_path"]))
    mask = np.asarray(Image.open(path.parent / f["mask_path"])) > 0
    assert color.shape == (192, 288, 3) and 0.05 < mask.mean() < 0.6
    assert len(meta["reference_sets"]["five"]) == 5


def test_cache_key_and_config_include_the_specimen():
    assert scene_key(SceneParams()) == "fc9ff3ae9003531d"  # the grain's folder is unchanged
    keys = {scene_key(SceneParams(specimen=s)) for s in ("grain", "diatom", "parts")}
    assert len(keys) == 3
    check_dataset_config({"kind": "synthetic", "specimen": "parts"})  # registered through checked(choices=...)
    with pytest.raises(ConfigError, match="specimen.*grain, diatom, parts"):
        check_dataset_config({"kind": "synthetic", "specimen": "sponge"})
