"""What each stage leaves after training: bars on its silent stretches (the final evaluation's views, the turntable's
frames: the demo spent 20 s in each stage's evaluation and video with nothing on the console), and one Chamfer score."""
from __future__ import annotations

from trainer_util import tiny_scene

from arcsem.plugins import BACKBONES
from arcsem.train.evaluate import evaluate_split
from arcsem.train.stage1 import turntable


def _backbone(scene):
    return BACKBONES.build({"name": "_tiny_image"}, scene=scene)


def test_evaluation_and_turntable_show_a_bar_only_when_asked(tmp_path, capsys):
    scene = tiny_scene()
    bb = _backbone(scene)
    evaluate_split(bb, scene.test, split_name="test", with_lpips=False, progress=False)
    turntable(bb, scene, tmp_path / "quiet", frames=3, fps=3, progress=False)
    assert capsys.readouterr().err == ""
    evaluate_split(bb, scene.test, split_name="test", with_lpips=False, progress=True)
    turntable(bb, scene, tmp_path / "turntable", frames=3, fps=3, progress=True)
    err = capsys.readouterr().err
    assert "evaluating test views" in err and "0/2" in err
    assert "turntable: rendering" in err and "0/3" in err


def test_only_stage_1_scores_its_mesh_against_the_true_surface(tmp_path, monkeypatch):
    """Stage 2 freezes the geometry: its coloured mesh is stage 1's surface, so the demo does not pay the Chamfer
    distance (4.6 s) twice."""
    from arcsem.colorize.outputs import write_colored_products
    from arcsem.mesh import extract
    from arcsem.train.products import write_products

    scored = []
    monkeypatch.setattr(extract, "ground_truth_chamfer",
                        lambda scene, v, f, n, cache_dir=None: scored.append(len(f)) or {"chamfer": 0})
    scene = tiny_scene()
    bb = _backbone(scene)
    cfg = {"mesh": {"formats": ["ply"], "carve": False, "alpha_min": 0.5, "use_masks": False}}
    grey = write_products(cfg, bb, scene, tmp_path)
    coloured = write_colored_products(cfg, bb, scene, tmp_path, 0, False)
    assert (tmp_path / "mesh.ply").exists() and (tmp_path / "colored_mesh.ply").exists()
    assert len(scored) == 1 and "gt" in grey["mesh"] and "gt" not in coloured["mesh"]
