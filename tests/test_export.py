"""Products of a finished run folder: ``arcsem-export`` (mesh PLY/GLB, viewer folder) and
``stage=render`` (H.264 orbit videos), on a run whose model is a known sphere (tests/run_util.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from run_util import R, make_run
from test_config import compose_with

from arcsem import app
from arcsem.cli.export import main as export_main


def snapshot(folder):
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("camera", ["pinhole", "orthographic"])
def test_export_mesh_and_viewer_folder(tmp_path, camera, capsys):
    import trimesh
    from plyfile import PlyData

    run = make_run(tmp_path, "gs2d", colored=True, camera=camera)
    before = snapshot(run)
    assert export_main([str(run), "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "mesh:" in printed and "colored_mesh:" in printed and "viewer:" in printed
    assert snapshot(run) == before  # the run folder is an input: nothing in it changed
    for prefix, inside in (("", (0.9, 0.1, 0.1)), ("colored_", (0.1, 0.2, 0.9))):
        ply = trimesh.load(tmp_path / "out" / f"{prefix}mesh.ply", process=False)
        glb = trimesh.load(tmp_path / "out" / f"{prefix}mesh.glb", force="mesh", process=False)
        assert len(ply.faces) > 100 and len(glb.faces) == len(ply.faces)
        r = np.linalg.norm(ply.vertices, axis=1)
        assert np.abs(r - R).mean() < 0.05, np.abs(r - R).mean()  # the sphere, within a voxel (0.05)
        right = ply.vertices[:, 0] > 0.2  # the x > 0 half has the first colour
        rgb = ply.visual.vertex_colors[right, :3].mean(0) / 255
        np.testing.assert_allclose(rgb, inside, atol=0.15)
        np.testing.assert_allclose(glb.visual.vertex_colors[:, :3].mean(0), ply.visual.vertex_colors[:, :3].mean(0),
                                   atol=1)
        it = 5 if prefix else 10  # the steps of the stage-2 / stage-1 checkpoints
        v = PlyData.read(str(tmp_path / "out" / f"{prefix}viewer" / "point_cloud" / f"iteration_{it}" / "point_cloud.ply"))
        v = v["vertex"].data
        assert {"scale_0", "scale_1", "scale_2", "opacity", "rot_0", "f_dc_0"} <= set(v.dtype.names)
    cams = json.loads((tmp_path / "out" / "viewer" / "cameras.json").read_text())
    assert len(cams) == 6 and ("model" in cams[0]) == (camera == "orthographic")


def test_export_of_a_missing_run_is_one_line(tmp_path, capsys):
    assert export_main([str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "nowhere" in err[0]


def test_render_stage_writes_browser_videos(tmp_path):
    import imageio_ffmpeg

    run = make_run(tmp_path, "gs3d", colored=True)
    before = snapshot(run)
    cfg = compose_with("stage=render", f"render.run={run}", "render.frames=8", "render.fps=4", "render.width=48",
                       "render.elevation=30", "render.azimuth=[-90,90]")
    metrics = app.run(cfg, run_dir=tmp_path / "render")
    assert snapshot(run) == before
    vids = metrics["render"]["videos"]
    assert sorted(vids) == ["color", "depth", "gray", "normal"]
    for path in vids.values():
        gen = imageio_ffmpeg.read_frames(path)
        meta = next(gen)
        frames = [np.frombuffer(f, np.uint8).reshape(meta["size"][1], meta["size"][0], 3) for f in gen]
        assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p"), meta
        assert len(frames) == 8 and meta["fps"] == 4 and tuple(meta["size"]) == (48, 36)
        assert np.std(frames[0]) > 10  # the sphere is there, not a blank frame
    depth = metrics["render"]["depth_range"]
    assert 0 < depth[0] < depth[1]
    saved = json.loads((tmp_path / "render" / "metrics.json").read_text())
    assert saved["stage"] == "render" and saved["render"]["frames"] == 8


def test_render_stage_needs_a_run(tmp_path):
    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="render.run"):
        app.run(compose_with("stage=render"), run_dir=tmp_path / "r")
    with pytest.raises(ConfigError, match="render.layers"):
        app.run(compose_with("stage=render", f"render.run={tmp_path}", "render.layers=[sepia]"),
                run_dir=tmp_path / "r")
