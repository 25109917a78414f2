"""Viewer-ready Gaussians: the INRIA folder layout read back with plyfile (the fields a 3DGS viewer
reads), 2DGS with a thin third scale and its native 2-scale file, cameras.json, the baked ACT."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from arcsem.backbones.gaussians.inria import THIN_RATIO, bake_act
from plyfile import PlyData
from test_backbone_contract import tiny_scene

from arcsem.act import ACT
from arcsem.plugins import BACKBONES

# what the INRIA reference viewer / SIBR / common web viewers read from every vertex
VIEWER_FIELDS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                 "rot_0", "rot_1", "rot_2", "rot_3"]


def build(name: str, model: str = "pinhole", act: bool = False):
    scene = tiny_scene(model)
    cls = BACKBONES.get(name)
    torch.manual_seed(0)
    kw = {"act": ACT(len(scene.train), init_noise=0.2)} if act else {}
    return cls(cls.Config(), scene=scene, **kw), scene


def read_vertices(path) -> np.ndarray:
    ply = PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"]
    return ply["vertex"].data


@pytest.mark.parametrize("name", ["gs2d", "gs3d"])
def test_folder_layout_and_fields(tmp_path, name):
    bb, scene = build(name)
    paths = bb.export_viewer(str(tmp_path / "viewer"), scene.train.cameras, scene.train.names,
                             scene.bounds.mean(0), iteration=1500)
    ply = tmp_path / "viewer" / "point_cloud" / "iteration_1500" / "point_cloud.ply"
    assert paths["ply"] == str(ply)
    v = read_vertices(ply)
    names = v.dtype.names
    assert all(f in names for f in VIEWER_FIELDS), set(VIEWER_FIELDS) - set(names)
    assert [n for n in names if n.startswith("f_rest_")] == [f"f_rest_{i}" for i in range(45)]
    assert all(v.dtype[n] == np.dtype("<f4") for n in names)
    p = bb.model.params()
    assert len(v) == len(p["means"])
    np.testing.assert_allclose(np.stack([v["x"], v["y"], v["z"]], 1), p["means"].detach().numpy(), rtol=0, atol=0)
    np.testing.assert_allclose(np.stack([v[f"rot_{i}"] for i in range(4)], 1), p["quats"].detach().numpy())
    s = np.stack([v[f"scale_{i}"] for i in range(3)], 1)
    if name == "gs2d":
        s2 = p["log_scales"].detach().numpy()
        np.testing.assert_allclose(s[:, :2], s2)
        np.testing.assert_allclose(s[:, 2], s2.min(1) + math.log(THIN_RATIO), rtol=1e-6)
        native = read_vertices(paths["native_ply"])
        assert "scale_2" not in native.dtype.names and "scale_1" in native.dtype.names
        np.testing.assert_allclose(native["scale_1"], s2[:, 1])
    else:
        assert "native_ply" not in paths
        np.testing.assert_allclose(s, p["log_scales"].detach().numpy())
    assert "sh_degree=3" in (tmp_path / "viewer" / "cfg_args").read_text()


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_cameras_json(tmp_path, model):
    bb, scene = build("gs3d", model)
    cams = scene.train.cameras
    centre = scene.bounds.mean(0)
    bb.export_viewer(str(tmp_path), cams, scene.train.names, centre, iteration=7)
    entries = json.loads((tmp_path / "cameras.json").read_text())
    assert [e["img_name"] for e in entries] == scene.train.names and [e["id"] for e in entries] == [0, 1, 2]
    for i, e in enumerate(entries):
        assert (e["width"], e["height"]) == (cams.width, cams.height)
        R = np.array(e["rotation"])
        w2c = cams.world_to_cam[i].double().numpy()
        np.testing.assert_allclose(R, w2c[:3, :3].T, atol=1e-6)  # camera-to-world rotation
        np.testing.assert_allclose(np.array(e["position"]), cams.centers[i].double().numpy(), atol=1e-5)
        f = float(cams.K[i, 0, 0])
        if model == "pinhole":
            assert e["fx"] == pytest.approx(f) and "model" not in e
        else:  # the pinhole with the same footprint at the centre: fx = f_ortho * distance
            dist = float((centre.double() - cams.centers[i].double()) @ cams.forward[i].double())
            assert e["model"] == "orthographic" and e["fx_orthographic"] == pytest.approx(f)
            assert e["fx"] == pytest.approx(f * dist, rel=1e-6)


def test_mean_act_is_baked_into_the_colours():
    bb, scene = build("gs3d", act=True)
    cams = scene.train.cameras[:1]
    cams.image_ids[:] = -1
    with torch.no_grad():
        plain = bb.model.colors(cams)
        want = bb.act.apply(plain, cams.image_ids)
        assert (want - plain).abs().max() > 0.05  # the ACT does change the colours
        baked = bake_act(bb.model.params(), bb.act)
        bb.model.sh_dc.copy_(baked["sh_dc"])
        bb.model.sh_rest.copy_(baked["sh_rest"])
        got = bb.model.colors(cams).clamp(0, 1)
    inside = (want > 0.01) & (want < 0.99)  # the clamps of ACT and SH decoding happen at different places
    assert inside.float().mean() > 0.5
    torch.testing.assert_close(got[inside], want[inside], atol=1e-5, rtol=1e-5)
