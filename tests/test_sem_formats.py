"""SEM sample formats read over their real intensity range (8/12/16/32-bit integers, floats), by both readers
(the calibration's :func:`read_sem_image` and the datasets' :func:`arcsem.data.io.read_image`), and colour TIFFs:
grey content read as grey, colour content read with a warning naming the file."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import tifffile

from arcsem.data.io import read_image
from arcsem.sem.image import read_sem_image


def ramp(h: int = 40, w: int = 64) -> np.ndarray:
    """``[h, w]`` float64 in [0, 1]: a horizontal ramp with a vertical ripple (every level used)."""
    x = np.linspace(0.0, 1.0, w)[None, :]
    y = 0.5 + 0.5 * np.sin(np.linspace(0, 3 * np.pi, h))[:, None]
    return 0.8 * x + 0.2 * y


def write(path, data, **kw):
    tifffile.imwrite(path, data, metadata=None, **kw)
    return path


def both(path):
    """(SEM reader's image, the dataset reader's grey channel in [0, 1])."""
    return read_sem_image(path), read_image(path)[0][..., 0]


def test_float_raw_detector_counts_use_the_data_range(tmp_path):
    """float32 holding counts 0..65535 (not [0, 1]) was clipped to white by the dataset reader (every pixel 1.0)."""
    counts = (ramp() * 60000 + 2000).astype(np.float32)
    im, grey = both(write(tmp_path / "f.tif", counts))
    assert im.levels.source == "the data's 0.1/99.9 percentiles"
    assert im.levels.lo == pytest.approx(np.percentile(counts, 0.1)) and im.levels.hi == pytest.approx(
        np.percentile(counts, 99.9))
    expect = np.clip((counts - im.levels.lo) / (im.levels.hi - im.levels.lo), 0, 1)
    np.testing.assert_allclose(grey, expect, atol=1 / 65535)
    np.testing.assert_allclose(im.pixels / 65535.0, expect, atol=1 / 65535)
    assert 0.3 < grey.mean() < 0.7                               # not white


def test_uint32_counts_beyond_sixteen_bits(tmp_path):
    """uint32 samples (here up to 200,000) were clipped at 65535 (SEM reader) or to white (dataset reader)."""
    counts = np.round(ramp() * 200_000).astype(np.uint32)
    im, grey = both(write(tmp_path / "u32.tif", counts))
    assert im.bits == 16 and "percentiles" in im.levels.source
    assert np.corrcoef(im.pixels.ravel(), counts.ravel())[0, 1] > 0.999
    assert (im.pixels == 65535).mean() < 0.01 and 0.3 < grey.mean() < 0.7


def test_float_in_unit_range_is_taken_as_it_is(tmp_path):
    unit = ramp().astype(np.float32)
    im, grey = both(write(tmp_path / "unit.tif", unit))
    assert (im.levels.lo, im.levels.hi, im.levels.source) == (0.0, 1.0, "float samples within [0, 1]")
    np.testing.assert_allclose(grey, unit, atol=0.6 / 65535)


def test_range_tags_of_the_file_win(tmp_path):
    """SMinSampleValue/SMaxSampleValue (any type) and MaxSampleValue (integers): the range the file declares."""
    counts = (ramp() * 20000).astype(np.float32)
    im, grey = both(write(tmp_path / "s.tif", counts, extratags=[(340, 11, 1, 0.0, True), (341, 11, 1, 40000.0, True)]))
    assert im.levels.describe() == "0..40000 (SMinSampleValue/SMaxSampleValue tags)"
    np.testing.assert_allclose(grey, counts / 40000.0, atol=1 / 65535)
    twelve = np.round(ramp() * 4095).astype(np.uint16)          # 12-bit data in 16-bit samples
    im, grey = both(write(tmp_path / "m.tif", twelve, extratags=[(281, 3, 1, 4095, True)]))
    assert im.levels.describe() == "0..4095 (MinSampleValue/MaxSampleValue tags)"
    np.testing.assert_allclose(grey, twelve / 4095.0, atol=0.6 / 65535)


def test_bits_per_sample(tmp_path):
    """12-bit packed samples span 0..4095 (read as 0..65535 they were 16x too dark); 8 and 16 bits stay as stored."""
    twelve = np.round(ramp() * 4095).astype(np.uint16)
    im, grey = both(write(tmp_path / "b12.tif", twelve, bitspersample=12))
    assert im.levels.describe() == "0..4095 (BitsPerSample 12)"
    np.testing.assert_allclose(grey, twelve / 4095.0, atol=0.6 / 65535)
    for dtype, top in ((np.uint8, 255), (np.uint16, 65535)):
        data = np.round(ramp() * top).astype(dtype)
        im, grey = both(write(tmp_path / f"b{top}.tif", data))
        assert im.levels.describe() == f"0..{top} (BitsPerSample {8 * data.itemsize})"
        np.testing.assert_array_equal(im.pixels, data)


def test_signed_integers_use_the_data_range(tmp_path):
    signed = np.round(ramp() * 3000 - 1500).astype(np.int16)
    im, grey = both(write(tmp_path / "i16.tif", signed))
    assert "percentiles" in im.levels.source and im.levels.lo < -1400 and im.levels.hi > 1400
    assert np.corrcoef(grey.ravel(), signed.ravel())[0, 1] > 0.999


def test_nan_samples_are_an_error(tmp_path):
    from arcsem.errors import DataError

    bad = ramp().astype(np.float32)
    bad[3, 5] = np.nan
    with pytest.raises(DataError, match=r"nan\.tif: 1 pixel value\(s\) are NaN or infinite \(first at x=5, y=3\)"):
        read_sem_image(write(tmp_path / "nan.tif", bad))


@pytest.mark.parametrize("channels", [3, 4])
def test_colour_tiff_of_grey_content_is_grey(tmp_path, channels):
    """RGB(A) of one grey whose channels differ by a level or two (a lossy codec, a converter's rounding): grey, no
    warning (they were read as colour before: only exactly equal channels counted as grey)."""
    grey8 = np.round(ramp() * 253 + 1).astype(np.uint8)
    wobble = np.random.default_rng(0).integers(-1, 2, size=(*grey8.shape, 3))
    rgb = (grey8[..., None] + wobble).astype(np.uint8)
    if channels == 4:
        rgb = np.concatenate([rgb, np.full_like(grey8, 255)[..., None]], -1)
    path = write(tmp_path / "g.tif", rgb, photometric="rgb", compression="lzw")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        im = read_sem_image(path)
    assert im.pixels.shape == grey8.shape and not any("colour" in n for n in im.notes)
    assert np.abs(im.pixels.astype(int) - grey8).max() <= 4


def test_colour_content_warns_naming_the_file(tmp_path):
    rgb = np.zeros((40, 64, 3), np.uint8)
    rgb[..., 0] = np.round(ramp() * 255)                          # red only: colour
    path = write(tmp_path / "red.tif", rgb, photometric="rgb")
    with pytest.warns(UserWarning, match=r"red\.tif: a colour image .* read as its luminance"):
        im = read_sem_image(path)
    np.testing.assert_allclose(im.pixels, np.round(rgb[..., 0] * 0.299), atol=1)
    assert "colour image read as its luminance" in im.notes


def test_four_bit_palette_image_spans_the_grey_range(tmp_path):
    """A 4-bit palette (indices 0..15): its colour map gives 8-bit grey; the index depth is not the grey range."""
    idx = (np.arange(40 * 64).reshape(40, 64) % 16).astype(np.uint8)
    cmap = np.zeros((3, 256), np.uint16)                    # tifffile writes 256 entries; 16 used: grey 0..65535
    cmap[:, :16] = np.arange(16) * 4369
    im = read_sem_image(write(tmp_path / "p.tif", idx, photometric="palette", colormap=cmap, bitspersample=4))
    np.testing.assert_array_equal(im.pixels, np.round(idx.astype(float) * 4369 / 65535 * 255).astype(np.uint8))


def test_min_is_white_is_read_inverted(tmp_path):
    """PhotometricInterpretation 0 (min-is-white): the smallest sample is white; it was read as black."""
    grey8 = np.round(ramp() * 255).astype(np.uint8)
    im, grey = both(write(tmp_path / "w.tif", grey8, photometric="miniswhite"))
    np.testing.assert_array_equal(im.pixels, 255 - grey8)
    np.testing.assert_allclose(grey, (255 - grey8) / 255.0, atol=1e-6)
    assert "min-is-white" in im.levels.source
    plain, _ = both(write(tmp_path / "b.tif", grey8))
    np.testing.assert_array_equal(plain.pixels, grey8)


def test_more_than_four_samples_per_pixel_is_one_clear_error(tmp_path):
    from arcsem.errors import DataError

    path = write(tmp_path / "many.tif", np.zeros((16, 24, 32), np.uint8), planarconfig="separate",
                 photometric="minisblack")
    with pytest.raises(DataError, match=r"many.tif: an image of 16 samples per pixel"):
        read_image(path)


def test_the_intensity_range_is_recorded_in_metrics_json(tmp_path):
    """A dataset of float32 TIFF views holding raw counts: the range each file was read over (the data's
    percentiles) is printed by stage=check and recorded in metrics.json (dataset.intensity)."""
    import contextlib
    import io
    import json

    from conftest import write_transforms_scene
    from hydra import compose, initialize_config_module

    from arcsem import app

    scene = write_transforms_scene(tmp_path / "scene", n=4, w=32, h=24).parent
    frames = json.loads((scene / "transforms.json").read_text())
    for i, f in enumerate(frames["frames"]):
        write(scene / f"v{i}.tif", (ramp(24, 32) * 50000 + 1000 * i).astype(np.float32))
        f["file_path"] = f"v{i}.tif"
    (scene / "transforms.json").write_text(json.dumps(frames))
    overrides = ["dataset=transforms", f"dataset.path={scene}", "stage=check"]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), initialize_config_module("arcsem.conf", version_base="1.3"):
        app.run(compose("config", overrides=overrides), run_dir=tmp_path / "run", overrides=overrides)
    ranges = json.loads((tmp_path / "run" / "metrics.json").read_text())["dataset"]["intensity"]
    assert len(ranges) == 4 and all(r["views"] == 1 for r in ranges)
    first = next(r for r in ranges if r["first"].endswith("v0.tif"))
    lo, hi = np.percentile(ramp(24, 32) * 50000, (0.1, 99.9))
    assert first["levels"] == f"{lo:.6g}..{hi:.6g} (the data's 0.1/99.9 percentiles)"
    assert f"intensity  {first['levels']}: 1 view(s)" in out.getvalue()
