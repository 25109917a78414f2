"""``stage=check`` prints a one-screen summary of what it read, built and validated."""
from __future__ import annotations

from conftest import write_transforms_scene
from test_config import compose_with

from arcsem import app


def test_check_prints_a_one_screen_summary(tmp_path, capsys):
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "backbone=gs3d", "stage=check",
                       "act=none", "mesh.enabled=false")
    app.run(cfg, run_dir=tmp_path / "run")
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0].startswith("check: OK")
    assert 8 <= len(out) <= 24  # one screen
    text = "\n".join(out)
    for want in ("3 train + 0 held-out, 24x16 px, pinhole cameras", "ground truth: none",
                 "gs3d (arcsem.backbones.gs3d", "ACT        off", "mesh off", str(scene.parent)):
        assert want in text, want
    assert all(len(line) <= 110 for line in out if str(tmp_path) not in line), out


def test_check_says_the_grey_input_is_made_from_colour(tmp_path, capsys):
    import cv2

    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    img = cv2.imread(str(scene.parent / "view_00.png"))
    img[2:8, 2:8] = (0, 0, 255)
    cv2.imwrite(str(scene.parent / "view_00.png"), img)
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "dataset.grey=true", "backbone=gs3d",
                       "stage=check", "act=none", "mesh.enabled=false")
    app.run(cfg, run_dir=tmp_path / "run")
    out = capsys.readouterr().out
    assert "ground truth: colour (grey input: the colour views' luminance, dataset.grey=true)" in out
