"""References: presets and files matched by name; wrong size, unknown view, grey/empty content refused."""
import numpy as np
import pytest
import torch

from arcsem.colorize.analytic import arc_cameras
from arcsem.colorize.references import load_references
from arcsem.errors import ConfigError, DataError
from arcsem.scene import Scene, Split


def _scene(refs=None, sets=None):
    cams = arc_cameras(3, 16, 12)
    names = ["v0", "v1", "v2"]
    train = Split(names=names, cameras=cams, images=torch.rand(3, 12, 16, 3))
    test = Split(names=[], cameras=cams[[]], images=torch.zeros(0, 12, 16, 3))
    return Scene(root=".", train=train, test=test, bounds=torch.tensor([[-1.0] * 3, [1.0] * 3]),
                 references=refs or {}, reference_sets=sets or {})


def _png(path, arr):
    import imageio.v3 as iio

    iio.imwrite(path, (np.clip(arr, 0, 1) * 255).astype(np.uint8))
    return path


def test_preset_picks_named_views():
    col = torch.rand(12, 16, 3)
    sc = _scene({"v2": col, "v0": col}, {"two": ["v2", "v0"]})
    r = load_references(sc, "two")
    assert r.names == ["v2", "v0"] and r.indices.tolist() == [2, 0] and r.images.shape == (2, 12, 16, 3)
    with pytest.raises(ConfigError, match="unknown preset 'five'"):
        load_references(sc, "five")


def test_files_matched_by_stem(tmp_path):
    img = np.random.rand(12, 16, 3)
    p = _png(tmp_path / "v1.png", img)
    r = load_references(_scene(), [str(p)])
    assert r.names == ["v1"] and r.indices.tolist() == [1]
    np.testing.assert_allclose(r.images[0].numpy(), (np.clip(img, 0, 1) * 255).astype(np.uint8) / 255, atol=1e-6)


def test_a_folder_of_references_takes_every_image_the_readers_read(tmp_path):
    """A folder's references: every file with an image suffix the dataset readers take (one list, WebP included;
    lossless here, so the pixels are exact), other files left alone."""
    import cv2

    img = (np.random.default_rng(0).random((12, 16, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "v2.webp"), img[..., ::-1], [cv2.IMWRITE_WEBP_QUALITY, 101])
    _png(tmp_path / "v0.png", img / 255.0)
    (tmp_path / "notes.txt").write_text("v1")
    r = load_references(_scene(), str(tmp_path))
    assert sorted(r.names) == ["v0", "v2"]
    np.testing.assert_allclose(r.images[r.names.index("v2")].numpy(), img / 255.0, atol=1e-6)


def test_refusals_name_the_file(tmp_path):
    sc = _scene()
    with pytest.raises(DataError, match=r"wrong\.png.*matches no training view"):
        load_references(sc, [str(_png(tmp_path / "wrong.png", np.random.rand(12, 16, 3)))])
    with pytest.raises(DataError, match=r"v0\.png.*size 20x12 differs from view 'v0' \(16x12\)"):
        load_references(sc, [str(_png(tmp_path / "v0.png", np.random.rand(12, 20, 3)))])
    grey = np.repeat(np.random.rand(12, 16, 1), 3, -1)
    with pytest.raises(DataError, match=r"v1\.png.*grey"):
        load_references(sc, [str(_png(tmp_path / "v1.png", grey))])
    with pytest.raises(DataError, match=r"v2\.png.*empty"):
        load_references(sc, [str(_png(tmp_path / "v2.png", np.full((12, 16, 3), 0.5)))])
    with pytest.raises(DataError, match="does not exist"):
        load_references(sc, [str(tmp_path / "nope.png")])


def test_a_view_named_with_its_folder_takes_the_file_of_that_folder(tmp_path):
    """NeRF-synthetic folders repeat stems (train/r_0, test/r_0): views are named ``train/r_0`` and a reference
    given as the dataset's own ``.../train/r_0.png`` (RGBA) colours that view, over black as the reader takes it."""
    sc = _scene()
    sc.train.names[:] = ["train/r_0", "train/r_1", "train/r_2"]
    rgba = np.random.rand(12, 16, 4)
    rgba[..., 3] = np.arange(16) >= 8  # the left half transparent
    (tmp_path / "train").mkdir()
    r = load_references(sc, [str(_png(tmp_path / "train" / "r_1.png", rgba))])
    assert r.names == ["train/r_1"] and r.indices.tolist() == [1]
    assert float(r.images[0, :, :8].abs().max()) == 0.0 and float(r.images[0, :, 8:].min()) >= 0.0
    want = (np.clip(rgba[..., :3], 0, 1) * 255).astype(np.uint8)[:, 8:] / 255
    np.testing.assert_allclose(r.images[0, :, 8:].numpy(), want, atol=1e-6)
    with pytest.raises(DataError, match=r"r_1\.png.*matches no training view \(train/r_0"):  # a stem alone: no
        load_references(sc, [str(_png(tmp_path / "r_1.png", rgba))])


def test_a_reference_at_the_full_size_of_a_downscaled_view_is_resampled(tmp_path):
    """dataset.downscale=2 trains 16x12 views; the artist's reference at the files' 32x24 is the view's colour at
    twice the scale: resampled by area as the reader resamples the views. Another shape is still refused."""
    big = np.random.rand(24, 32, 3)
    r = load_references(_scene(), [str(_png(tmp_path / "v2.png", big))])
    stored = (np.clip(big, 0, 1) * 255).astype(np.uint8) / 255
    want = stored.reshape(12, 2, 16, 2, 3).mean((1, 3))  # area resampling by an integer factor: block means
    assert r.images.shape == (1, 12, 16, 3)
    np.testing.assert_allclose(r.images[0].numpy(), want, atol=1e-5)
    with pytest.raises(DataError, match=r"size 32x20 differs from view 'v2' \(16x12\) and is not the view at"):
        load_references(_scene(), [str(_png(tmp_path / "v2.png", np.random.rand(20, 32, 3)))])


def test_views_named_in_the_list_give_their_true_colour(tmp_path, monkeypatch):
    """``colorize.references=[v2, v0]`` on a dataset with colour ground truth (dataset.grey=true): each view's true
    colour is its reference; a file of that name wins; a bare word stays a preset, and its error says how."""
    sc = _scene()
    sc.train.colors = torch.rand(3, 12, 16, 3)
    r = load_references(sc, ["v2", "v0"])
    assert r.names == ["v2", "v0"] and torch.equal(r.images, sc.train.colors[[2, 0]])
    with pytest.raises(ConfigError, match=r"unknown preset 'v1'.*for view 'v1''s true colour write \[v1\]"):
        load_references(sc, "v1")
    monkeypatch.chdir(tmp_path)
    img = np.random.rand(12, 16, 3)
    (tmp_path / "v1").mkdir()
    _png(tmp_path / "v1" / "v1.png", img)  # a folder named as the view: its images are the references
    r = load_references(sc, ["v1"])
    assert not torch.equal(r.images[0], sc.train.colors[1])
    np.testing.assert_allclose(r.images[0].numpy(), (np.clip(img, 0, 1) * 255).astype(np.uint8) / 255, atol=1e-6)
    sc.train.colors = None  # no true colour: a name is a file that does not exist
    with pytest.raises(DataError, match="reference file 'v2' does not exist"):
        load_references(sc, ["v2"])
