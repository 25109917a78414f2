"""Issue 40's answers that the hostile-input table does not show by itself: the figures of the memory estimate,
the grey reading of RGB files, and the reasons metrics.json gives for its nulls."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import write_transforms_scene


def test_load_bytes_of_three_12000_px_views():
    from arcsem.data.headers import load_bytes

    # kept: 3 x 144e6 px x 12 B = 5.184e9, twice for the stack; one decode: 144e6 x 40 B = 5.76e9 on top of the kept
    assert load_bytes([(12000, 12000)] * 3, 1.0) == max(2 * 5_184_000_000, 5_184_000_000 + 5_760_000_000)
    # at downscale 4 the kept images are 16x smaller, the full-size decode stays
    assert load_bytes([(12000, 12000)] * 3, 4.0) == 324_000_000 + 5_760_000_000


def test_image_header_sizes(tmp_path):
    import cv2

    from arcsem.data.headers import image_header

    img = np.zeros((24, 32), np.uint8)
    for ext in (".png", ".jpg", ".bmp", ".tif"):
        cv2.imwrite(str(tmp_path / f"a{ext}"), img)
        assert image_header(tmp_path / f"a{ext}") == (32, 24), ext
    (tmp_path / "b.png").write_text("not an image")
    assert image_header(tmp_path / "b.png") is None


def test_rgb_of_grey_content_reads_as_grey_and_colour_stays():
    from arcsem.data.io import grey_if_equal_channels

    g = np.random.default_rng(0).random((24, 32, 1)).astype(np.float32)
    jpeg_like = np.concatenate([g, g + 1 / 255, g - 2 / 255], -1)  # a colour JPEG of a grey picture: 1-2/255 apart
    out, coloured = grey_if_equal_channels(jpeg_like)
    assert coloured == 0.0 and np.array_equal(out[..., 0], out[..., 2])
    np.testing.assert_allclose(out[..., 0], (g[..., 0] + (g[..., 0] + 1 / 255) + (g[..., 0] - 2 / 255)) / 3, rtol=1e-6)
    colour = np.concatenate([g, 1 - g, g * 0], -1)
    out, coloured = grey_if_equal_channels(colour)
    assert out is colour and coloured > 0.5


def test_channel_spread_is_max_minus_min_whichever_channel_is_which():
    from itertools import permutations

    from arcsem.data.io import channel_spread

    x = np.random.default_rng(1).random((16, 16, 3)).astype(np.float32)
    for order in permutations(range(3)):  # the largest and smallest channel in every position
        y = x[..., list(order)]
        assert np.array_equal(channel_spread(y), y.max(-1) - y.min(-1))


def test_strict_metrics_nulls_with_reasons():
    from arcsem.metrics_json import strict_metrics

    m = {"stage1": {"lpips_weights": "skipped", "train": {"psnr": math.inf, "ssim": 0.5, "lpips": math.nan}},
         "stage2": {"coverage": math.nan, "views": [1.0, -math.inf]}}
    out = strict_metrics(m)
    assert out["stage1"]["train"] == {"psnr": None, "ssim": 0.5, "lpips": None}
    assert out["stage2"] == {"coverage": None, "views": [1.0, None]}
    assert out["nulls"] == {
        "stage1.train.psnr": "Infinity: the render equals the image (no error)",
        "stage1.train.lpips": "NaN: LPIPS not computed (lpips_weights: skipped)",
        "stage2.coverage": "NaN: no value: nothing to measure it on (no view, pixel, match or time)",
        "stage2.views.1": "-Infinity: out of the float range",
    }
    json.dumps(out, allow_nan=False)  # strict JSON
    assert math.isnan(m["stage1"]["train"]["lpips"])  # the run's own dict is unchanged


@pytest.mark.slow
def test_metrics_json_of_a_run_is_strict_and_says_why(tmp_path):
    from test_config import compose_with

    from arcsem import app

    scene = write_transforms_scene(tmp_path / "scene", n=4, w=32, h=24)
    tiny = ["train.width=null", "threads=1", "train.steps=2", "train.eval.video=false", "train.eval.lpips=false",
            "train.progress=false", "backbone.random_init_points=100", "mesh.enabled=false"]
    app.run(compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=gray", *tiny),
            run_dir=tmp_path / "run")
    text = (tmp_path / "run" / "metrics.json").read_text()
    data = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert data["stage1"]["train"]["lpips"] is None
    assert data["nulls"]["stage1.train.lpips"] == "NaN: LPIPS not computed (lpips_weights: skipped)"
