"""The silent stretches of a run have bars: the final evaluation's views and the turntable's frames (the demo spent
20 s in each stage's evaluation and video with nothing on the console)."""
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
