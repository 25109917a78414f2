"""The bad-input table, part 1: values and files refused before anything is trained.

Each case runs the ``arcsem`` console script on a tiny dataset and checks the exit code, the one
``error:`` line (it names the key, file or view) and that no input file changed. The run-time cases
(outputs, checkpoints, environment, Ctrl-C, locks) are in test_bad_inputs_runs.py.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from bad_input_util import TINY, dataset, one_error_line, run_cli, tree_hashes
from conftest import write_transforms_scene

pytestmark = pytest.mark.slow  # each case starts the console script (a few seconds of imports)

SINGULAR = [[0.0] * 4, [0.0] * 4, [0.0] * 4, [0, 0, 0, 1]]
SCALED = [[2.0, 0, 0, 0], [0, 2.0, 0, 0], [0, 0, 2.0, 4.0], [0, 0, 0, 1]]


def frame(i, **kw):
    return lambda m: m["frames"][i].update(**kw)


# name -> (dataset edit, extra overrides, stage, needles of the error line)
CONFIG_CASES = {
    "singular pose": (frame(1, transform_matrix=SINGULAR), [], "check", ["frame 1", "view_01", "singular"]),
    "scaled pose": (frame(2, transform_matrix=SCALED), [], "check", ["frame 2", "not orthonormal"]),
    "focal 0": (lambda m: m.update(fl_x=0), [], "check", ["transforms.json", "'fl_x' must be a positive number, got 0"]),
    "focal string": (lambda m: m.update(fl_x="abc"), [], "check", ["'fl_x' must be a positive number, got 'abc'"]),
    "negative focal": (lambda m: m.update(fl_y=-20), [], "check", ["'fl_y' must be a positive number, got -20"]),
    "distortion string": (lambda m: m.update(k1="x"), [], "check", ["'k1' must be a finite number"]),
    "act.mode=foo": (None, ["act.mode=foo"], "check", ["act.mode: must be one of rgb, scalar, got 'foo'"]),
    "device=cuda": (None, ["device=cuda"], "check", ["device=cuda: no CUDA device", "use device=cpu"]),
    "device=tpu": (None, ["device=tpu"], "check", ["device: 'tpu'"]),
    "seed=abc": (None, ["seed=abc"], "check", ["seed: expected an integer, got 'abc'"]),
    "max_views=-1": (None, ["dataset.max_views=-1"], "check", ["dataset.max_views: must be >= 2, got -1"]),
    "dataset.downscale=0": (None, ["dataset.downscale=0"], "check", ["dataset.downscale: must be >= 1.0, got 0"]),
    "train.downscale=0": (None, ["train.downscale=0"], "check", ["train.downscale: must be >= 1.0, got 0"]),
    "train.width=0": (None, ["train.width=0"], "check", ["train.width: must be >= 1, got 0"]),
    "train.width=5": (None, ["train.width=5"], "check", ["train.width: training images would be 5x4 px"]),
    "train.steps=0": (None, ["train.steps=0"], "gray", ["train.steps: must be >= 1, got 0"]),
    "train.steps=-5": (None, ["train.steps=-5"], "gray", ["train.steps: must be >= 1, got -5"]),
    "colorize.steps=-3": (None, ["colorize.steps=-3"], "color", ["colorize.steps: must be >= 1, got -3"]),
    "checkpoint_every=-1": (None, ["train.checkpoint_every=-1"], "gray", ["train.checkpoint_every: must be >= 0"]),
    "resume=maybe": (None, ["train.resume=maybe"], "gray", ["train.resume: must be one of auto, never, must"]),
    "backbone key range": (None, ["backbone.densify_every=0"], "gray", ["backbone 'gs2d'", "densify_every: must be >= 1"]),
    "backbone key typo": (None, ["backbone.densify_evry=5"], "gray", ["backbone.densify_evry: unknown key"]),
    "colorize.masks=dataset": (None, ["colorize.masks=dataset"], "all", ["colorize.masks=dataset", "no masks"]),
    "references=seven": (None, ["colorize.references=seven"], "all", ["colorize.references: unknown preset 'seven'"]),
    "references file": (None, ["colorize.references=/nowhere/ref.png"], "all",
                        ["colorize.references: file or folder not found: /nowhere/ref.png"]),
    # in a list, a name without an image suffix may be a view's (read with the data): still refused before training
    "references list name": (None, ["colorize.references=[nowhere/r_0]"], "all",
                             ["reference file 'nowhere/r_0' does not exist (nor is it a training view"]),
    "features=sift": (None, ["colorize.features=sift"], "all", ["colorize.features: must be one of auto, vgg16"]),
    "tcm_space=features daisy": (None, ["colorize.features=daisy", "colorize.tcm_space=features", "colorize.losses.tcm.weight=1"],
                                 "all", ["colorize.tcm_space=features: 'daisy' features cannot be computed"]),
    "stage=paint": (None, ["stage=paint"], None, ["stage: unknown stage 'paint'"]),
    "threads=0": (None, ["threads=0"], "check", ["threads: expected a positive integer or null, got 0"]),
    "flag -7": (None, ["train.eval.video=-7"], "check", ["train.eval.video: must be true or false, got '-7'"]),
    "backbone flag 1": (None, ["backbone.densify=1"], "check", ["backbone.densify: must be true or false, got '1'"]),
}


@pytest.mark.parametrize("case", sorted(CONFIG_CASES))
def test_refused_before_training(tmp_path, case):
    edit, extra, stage, needles = CONFIG_CASES[case]
    ds = dataset(tmp_path / "scene", edit=edit)
    before = tree_hashes(tmp_path / "scene")
    run = tmp_path / "run"
    stage_arg = [f"stage={stage}"] if stage else []
    line = one_error_line(run_cli(tmp_path, *stage_arg, *ds, *TINY, f"hydra.run.dir={run}", *extra))
    for needle in needles:
        assert needle in line, line
    assert tree_hashes(tmp_path / "scene") == before
    assert not (run / "checkpoints").exists()  # refused before stage 1 trained anything


PLENOXELS_TINY = [a for a in TINY if not a.startswith("backbone.")]  # random_init_points is a Gaussian key
PLENOXELS_CASES = {  # name -> (overrides, stage, needles): the plugin's Config ranges, and its grid shape
    "lr_sh=0": (["backbone.lr_sh=0"], "check", ["backbone 'plenoxels'", "lr_sh: must be > 0.0, got 0"]),
    "upsample_every=0": (["backbone.upsample_every=0"], "check", ["upsample_every: must be >= 1, got 0"]),
    "tv_sparse_frac=2": (["backbone.tv_sparse_frac=2"], "check", ["tv_sparse_frac: must be <= 1.0, got 2"]),
    "reso side 1": (["backbone.reso=[[64,64,1]]"], "gray", ["reso must be a list of [X, Y, Z] with sides >= 2"]),
}


@pytest.mark.parametrize("case", sorted(PLENOXELS_CASES))
def test_plenoxels_config_refused_before_training(tmp_path, case):
    extra, stage, needles = PLENOXELS_CASES[case]
    ds = dataset(tmp_path / "scene")
    run = tmp_path / "run"
    line = one_error_line(run_cli(tmp_path, f"stage={stage}", "backbone=plenoxels", *ds, *PLENOXELS_TINY,
                                  f"hydra.run.dir={run}", *extra))
    for needle in needles:
        assert needle in line, line
    assert not (run / "checkpoints").exists()


def _one_pixel(root):
    write_transforms_scene(root, n=3, w=1, h=1)


def _nan_pixel(root):
    write_transforms_scene(root, n=4, w=32, h=24, ext=".tif")
    img = np.random.default_rng(0).random((24, 32)).astype(np.float32)
    img[3, 5] = math.nan
    cv2.imwrite(str(root / "view_01.tif"), img)


def _single_view(root):
    write_transforms_scene(root, n=1, w=32, h=24)


DATA_CASES = {  # name -> (writer, needles): the message names the real problem, not a loss that went NaN
    "1x1 images": (_one_pixel, ["the images are 1x1 px", "at least 11x11"]),
    "NaN pixel": (_nan_pixel, ["view_01.tif", "NaN or infinite", "x=5, y=3"]),
    "single view": (_single_view, ["1 training view(s)", "at least 2"]),
}


@pytest.mark.parametrize("case", sorted(DATA_CASES))
def test_bad_images_are_named(tmp_path, case):
    writer, needles = DATA_CASES[case]
    writer(tmp_path / "scene")
    before = tree_hashes(tmp_path / "scene")
    line = one_error_line(run_cli(tmp_path, "stage=gray", "dataset=transforms", f"dataset.path={tmp_path / 'scene'}",
                                  *TINY, f"hydra.run.dir={tmp_path / 'run'}"))
    for needle in needles:
        assert needle in line, line
    assert tree_hashes(tmp_path / "scene") == before


def test_null_distortion_reads_as_none(tmp_path):
    """``k1: null`` (as some exporters write it) means no distortion, not a crash."""
    ds = dataset(tmp_path / "scene", edit=lambda m: m.update(k1=None, p1=None))
    proc = run_cli(tmp_path, "stage=check", *ds, f"hydra.run.dir={tmp_path / 'run'}")
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_train_width_above_the_images_is_capped_with_a_warning(tmp_path):
    """``train.width=288`` on 32-px images trains at 32 px and says so (never a silent upsampling)."""
    import json

    ds = dataset(tmp_path / "scene")
    tiny = [o for o in TINY if not o.startswith("train.width")]
    proc = run_cli(tmp_path, "stage=gray", *ds, *tiny, "train.width=288", f"hydra.run.dir={tmp_path / 'run'}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["stage1"]["image_size"] == [32, 24]
    assert any("train.width=288 is wider than the images (32 px)" in w for w in metrics["warnings"])
    assert "train.width=288 is wider" in proc.stdout + proc.stderr


def test_sweep_prints_one_line_per_failed_job_and_exits_2(tmp_path):
    ds = dataset(tmp_path / "scene")
    proc = run_cli(tmp_path, "-m", "stage=check", *ds, "seed=1,abc", f"hydra.sweep.dir={tmp_path / 'sweep'}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "Error executing job" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    job = f"job 1 (stage=check dataset=transforms dataset.path={tmp_path / 'scene'} seed=abc)"
    assert errors == [f"error: {job}: seed: expected an integer, got 'abc'"]
    assert (tmp_path / "sweep" / "0" / "metrics.json").is_file()  # the good job still ran
    assert "sweep: 1 job(s) failed" in proc.stderr
