"""arcsem.report's images: grids of ground truth beside each row's renders (held-out or training views, shared
stage-1 models, references marked, a grid per dataset), the training curves and the videos' posters.

The run folders built here are fixtures shaped like what ``arcsem`` writes, not mocks of the product.
"""
from __future__ import annotations

import json

import numpy as np
import yaml
from report_util import _png

from arcsem.report import build_report


def test_ground_truth_rendered_from_the_runs_dataset(tmp_path, tiny_transforms):
    """No GT file in the run: the grid's GT tile is the dataset's image, read back via load_scene."""
    import cv2

    scene_json = tiny_transforms(n=4)
    run = tmp_path / "runs" / "r"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(yaml.safe_dump({"seed": 0, "dataset": {"kind": "transforms",
                                                                             "path": str(scene_json)}}))
    (run / "metrics.json").write_text(json.dumps({"seed": 0, "overrides": [], "stage1": {"train": {"psnr": 20.0}}}))
    _png(run / "renders/test/view_01.png", 10)
    build_report([tmp_path / "runs"], tmp_path / "rep")
    tile = cv2.imread(str(tmp_path / "rep" / "grids" / "gt" / "gray_view_01.png"))
    src = cv2.imread(str(scene_json.parent / "view_01.png"), cv2.IMREAD_GRAYSCALE)
    assert tile is not None and np.abs(tile[..., 0].astype(int) - src).max() <= 1
    assert not (tmp_path / "rep" / "grids" / "gt" / "depth_view_01.png").exists()  # no GT depth in this dataset


def test_grid_falls_back_to_training_view_renders(tmp_path):
    """A dataset without held-out views: the grids show renders/train/ (and say so)."""
    from arcsem.report.grids import study_grids

    run = tmp_path / "r"
    _png(run / "renders/train/a.png", 70)
    _png(run / "renders/train/a_depth.png", 80)
    grids = study_grids("grayscale_comparison", {"3DGS": run}, tmp_path / "g")
    assert [t for t, _ in grids] == ["grayscale_comparison: renders (training views)",
                                     "grayscale_comparison: depth maps (training views)"]
    import cv2

    img = cv2.imread(str(grids[1][1]))
    assert img[22 + 80, img.shape[1] - 5, 0] == 80 and img[22 + 80, 95, 0] == 200  # render; GT 'missing'


def test_grid_reads_renders_of_a_shared_stage1_model(tmp_path):
    """share_stage1: the run's stage-1 renders live behind its stage1/ link to the shared model."""
    from arcsem.report.grids import study_grids

    shared, run = tmp_path / "cache" / "abc", tmp_path / "r"
    _png(shared / "renders/test/a.png", 70)
    _png(shared / "renders/test/a_depth.png", 80)
    (shared / "turntable.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    run.mkdir()
    (run / "stage1").symlink_to(shared, target_is_directory=True)
    grids = study_grids("grayscale_comparison", {"2DGS": run}, tmp_path / "g")
    assert [t for t, _ in grids] == ["grayscale_comparison: renders (held-out views)",
                                     "grayscale_comparison: depth maps (held-out views)"]
    from arcsem.report.html import copy_videos

    videos = copy_videos("grayscale_comparison", {"2DGS": run}, tmp_path / "out")
    assert [c for c, _ in videos] == ["2DGS: turntable"] and videos[0][1].is_file()


def test_report_videos_get_a_poster_of_their_middle_frame(tmp_path):
    """A browser shows a black box for a <video> it has not loaded: each copied video gets its middle frame
    as poster."""
    import cv2
    import numpy as np

    from arcsem.report.html import _section, copy_videos
    from arcsem.report.tables import Table
    from arcsem.video import write_video

    run = tmp_path / "r"
    run.mkdir()
    frames = [np.full((64, 96, 3), 20 * i, np.uint8) for i in range(9)]   # frame i has grey level 20 i
    write_video(run / "turntable.mp4", frames, fps=5)
    videos = copy_videos("grayscale_comparison", {"2DGS": run}, tmp_path / "out")
    poster = videos[0][1].with_suffix(".jpg")
    assert poster.is_file() and abs(float(cv2.imread(str(poster)).mean()) - 80) < 6      # frame 4 of 9
    page = _section(Table("grayscale_comparison", [], [], [], None, []), [], videos, tmp_path / "out")
    assert 'poster="videos/grayscale_comparison/2DGS_turntable.jpg"' in page


def test_colour_grid_shows_held_out_views_and_marks_references(tmp_path):
    """The colour grid takes stage 2's held-out renders (colorize/renders/test/, title says so) where a run has
    them; from training views it marks the references (metrics.json stage2.references) beside their names."""
    import cv2

    from arcsem.report.grids import study_grids

    run = tmp_path / "r"
    _png(run / "colored/v0.png", 90)
    _png(run / "colored/v1.png", 95)
    (run / "metrics.json").write_text('{"stage2": {"references": ["v1"]}}')
    training = study_grids("reference_count", {"five": run}, tmp_path / "g1")
    assert [t for t, _ in training] == ["reference_count: coloured views"]
    marked = cv2.imread(str(training[0][1]))
    _png(run / "colorize/renders/test/t0.png", 60)
    _png(run / "colorize/renders/test/t0_gt.png", 61)
    held = study_grids("reference_count", {"five": run}, tmp_path / "g2")
    assert [t for t, _ in held] == ["reference_count: coloured views (held-out views)"]
    img = cv2.imread(str(held[0][1]))
    assert img[22 + 80, img.shape[1] - 5, 0] == 60 and img[22 + 80, 95, 0] == 61  # render; its true colour
    tile_h = marked.shape[0] // 2  # v0, v1: the reference's row label has a second line, "(reference)"
    row_label = lambda r: int((marked[r * tile_h: (r + 1) * tile_h, :90] < 128).any(-1).any(-1).sum())
    assert row_label(1) > 1.5 * row_label(0)


def test_runs_on_several_datasets_get_a_grid_each_with_their_own_views(tmp_path):
    """colorization_benchmark's scenes have views of their own names: one grid per dataset (config.yaml), each with
    its views and ground truth, its labels without the scene they share; no tile is "missing"."""
    import cv2

    from arcsem.report.grids import study_grids

    runs = {}
    for scene, views, level in (("grain", ["h_01", "v_09"], 60), ("chair", ["r_0", "r_88"], 120)):
        for variant in ("default", "pseudo-colours"):
            run = tmp_path / f"{scene}_{variant}"
            (run / "config.yaml").parent.mkdir(parents=True)
            (run / "config.yaml").write_text(f"dataset:\n  kind: transforms\n  path: /data/{scene}\n")
            for v in views:
                _png(run / f"colorize/renders/test/{v}.png", level)
                _png(run / f"colorize/renders/test/{v}_gt.png", level + 1)
            runs[f"{scene}, 1, {variant}"] = run
    grids = study_grids("colorization_benchmark", runs, tmp_path / "g")
    assert [t for t, _ in grids] == ["colorization_benchmark: coloured views (held-out views), grain",
                                     "colorization_benchmark: coloured views (held-out views), chair"]
    for (_, path), level in zip(grids, (60, 120)):
        img = cv2.imread(str(path))
        tiles = img[22:22 + 160 - 1, 90:, 0]  # the first view's row: the ground truth, then the two runs
        assert set(np.unique(tiles[80])) <= {level, level + 1, 255}  # no grey "missing" tile (200, its border 120)
    one = study_grids("colorization_benchmark", dict(list(runs.items())[:2]), tmp_path / "g1")
    assert [t for t, _ in one] == ["colorization_benchmark: coloured views (held-out views)"]  # one dataset: as before


def test_rows_sharing_a_stage1_model_draw_one_curve(tmp_path):
    """share_stage1: the default and pseudo-colour rows of one scene and seed link one stage-1 folder; the training
    curves draw it once, named by the first row and how many more share it; a model of its own stays its own."""
    from arcsem.report.curves import histories, training_curves

    shared = tmp_path / "cache" / "stage1" / "abc"
    shared.mkdir(parents=True)
    (shared / "train_history.csv").write_text("step,loss,psnr\n1,0.5,10\n2,0.4,12\n")
    runs = {}
    for label in ("grain, 1, default", "grain, 1, pseudo-colours", "grain, 3, default"):
        run = tmp_path / label.replace(", ", "_")
        run.mkdir()
        (run / "stage1").symlink_to(shared)
        runs[label] = run
    own = tmp_path / "own"
    own.mkdir()
    (own / "train_history.csv").write_text("step,loss,psnr\n1,0.6,9\n2,0.3,14\n")
    runs["diatom, 1, default"] = own
    got = histories(runs)
    assert list(got) == ["grain, 1, default (+2 rows)", "diatom, 1, default"]
    assert got["diatom, 1, default"]["psnr"].tolist() == [9, 14]
    assert training_curves(runs, tmp_path / "c.png").is_file()


def test_list_references_are_labelled_by_their_names_in_the_tiles():
    """References given as a list of files or view names fill a tile's width with their folders: the tile label
    keeps the names; presets and the rest of a label stay as they are."""
    from arcsem.report.grids import tile_label

    assert tile_label("[train/r_0,train/r_50]") == "r_0+r_50"
    assert tile_label("[/data/chair/train/r_0.png, /data/chair/train/r_50.png], default") == "r_0+r_50, default"
    assert tile_label("five, pseudo-colours") == "five, pseudo-colours"
