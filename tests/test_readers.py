"""Dataset readers: transforms.json (+NeRF-synthetic layout), COLMAP (pycolmap), images, PLY, splits."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import torch
from conftest import ring_poses, write_transforms_scene

from arcsem.data import ReaderOptions, load_scene, read_colmap, read_ply, read_transforms, write_ply
from arcsem.errors import DataError


def test_grey_8bit_cameras_and_pixels(tiny_transforms):
    path = tiny_transforms(n=3, w=16, h=12, fl=20.0)
    scene = read_transforms(path)
    raw = cv2.imread(str(path.parent / "view_01.png"), cv2.IMREAD_UNCHANGED)
    img = scene.train.images[1]
    assert img.shape == (12, 16, 3) and img.dtype == torch.float32
    np.testing.assert_allclose(img[..., 0].numpy(), raw / 255.0, atol=1e-7)
    assert torch.equal(img[..., 0], img[..., 2])  # grey -> three equal channels
    cams = scene.train.cameras
    np.testing.assert_allclose(cams.world_to_cam.numpy(), ring_poses(3), atol=1e-5)
    np.testing.assert_allclose(cams.K[0].numpy(), [[20, 0, 8.25], [0, 22, 5.5], [0, 0, 1]], atol=1e-5)
    assert scene.train.names == ["view_00", "view_01", "view_02"] and len(scene.test) == 0
    assert cams.image_ids.tolist() == [0, 1, 2]


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_grey_16bit(tiny_transforms, ext):
    path = tiny_transforms(n=2, ext=ext, bits=16)
    raw = cv2.imread(str(path.parent / f"view_00{ext}"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    img = read_transforms(path).train.images[0]
    np.testing.assert_allclose(img[..., 1].numpy(), raw / 65535.0, atol=1e-7)


def test_camera_angle_x_and_missing_extension(tiny_transforms):
    def strip(i, frame):
        frame["file_path"] = frame["file_path"][:-4]  # NeRF-synthetic style: no extension

    path = tiny_transforms(n=2, frame_extra=strip)
    meta = json.loads(path.read_text())
    for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        meta.pop(k)
    meta["camera_angle_x"] = 0.8
    path.write_text(json.dumps(meta))
    cams = read_transforms(path).train.cameras
    f = 0.5 * 16 / math.tan(0.4)  # w = 16 from the image itself
    np.testing.assert_allclose(cams.K[0].numpy(), [[f, 0, 8], [0, f, 6], [0, 0, 1]], rtol=1e-6)


def test_downscale_area(tiny_transforms):
    path = tiny_transforms(n=2, w=16, h=12)
    full = read_transforms(path)
    half = read_transforms(path, ReaderOptions(downscale=2))
    assert half.train.images.shape == (2, 6, 8, 3)
    blocks = full.train.images[0, :, :, 0].reshape(6, 2, 8, 2).mean((1, 3))  # INTER_AREA = 2x2 mean
    torch.testing.assert_close(half.train.images[0, :, :, 0], blocks, atol=1e-6, rtol=0)
    torch.testing.assert_close(half.train.cameras.K[0, :2], full.train.cameras.K[0, :2] / 2)
    assert (half.train.cameras.width, half.train.cameras.height) == (8, 6)


def test_split_modes(tiny_transforms):
    path = tiny_transforms(n=5, frame_extra=lambda i, f: f.update(split="test" if i == 3 else "train"))
    auto = read_transforms(path)
    assert auto.test.names == ["view_03"] and auto.test.cameras.image_ids.tolist() == [-1]
    every = read_transforms(path, ReaderOptions(split="every_k", test_every=2))
    assert every.test.names == ["view_00", "view_02", "view_04"]
    assert every.train.names == ["view_01", "view_03"] and every.train.cameras.image_ids.tolist() == [0, 1]
    assert len(read_transforms(path, ReaderOptions(split="none")).train) == 5
    few = read_transforms(path, ReaderOptions(split="none", max_views=3))
    assert few.train.names == ["view_00", "view_02", "view_04"]
    held = read_transforms(path, ReaderOptions(split="holdout", holdout=["view_01", "view_04"]))
    assert held.test.names == ["view_01", "view_04"] and held.train.names == ["view_00", "view_02", "view_03"]
    assert held.train.cameras.image_ids.tolist() == [0, 1, 2] and held.test.cameras.image_ids.tolist() == [-1, -1]
    with pytest.raises(DataError, match="dataset.holdout: unknown view.s. view_9; the views are view_00, view_01"):
        read_transforms(path, ReaderOptions(split="holdout", holdout=["view_9"]))
    with pytest.raises(DataError, match="dataset.holdout: no view named"):
        read_transforms(path, ReaderOptions(split="holdout"))


def test_nerf_synthetic_train_test_files(tmp_path):
    for split in ("train", "test"):
        meta = json.loads(write_transforms_scene(tmp_path / split, n=2, seed=len(split)).read_text())
        for f in meta["frames"]:  # NeRF-synthetic: "./train/r_0" relative to the folder, no extension
            f["file_path"] = f"./{split}/" + f["file_path"][:-4]
        (tmp_path / f"transforms_{split}.json").write_text(json.dumps(meta))
    scene = read_transforms(tmp_path)
    # stems collide across the two files: names fall back to the relative path without extension
    assert scene.train.names == ["train/view_00", "train/view_01"]
    assert scene.test.names == ["test/view_00", "test/view_01"]
    (tmp_path / "test" / "view_01.png").rename(tmp_path / "test" / "r_1.png")
    meta = json.loads((tmp_path / "transforms_test.json").read_text())
    meta["frames"][1]["file_path"] = "./test/r_1"
    (tmp_path / "transforms_test.json").write_text(json.dumps(meta))
    scene = read_transforms(tmp_path)
    assert scene.train.names == ["train/view_00", "view_01"] and scene.test.names == ["test/view_00", "r_1"]


def test_orthographic_aabb_extras(tiny_transforms, tmp_path):
    rng = np.random.default_rng(1)
    root = tmp_path / "scene"

    def extras(i, frame):
        root.mkdir(exist_ok=True)
        mask = np.zeros((12, 16), np.uint8)
        mask[2:8, 3:9] = 255
        cv2.imwrite(str(root / f"mask_{i}.png"), mask)
        np.save(root / f"depth_{i}.npy", rng.random((12, 16)).astype(np.float32))
        np.save(root / f"normal_{i}.npy", rng.random((12, 16, 3)).astype(np.float32))
        cv2.imwrite(str(root / f"color_{i}.png"), (rng.random((12, 16, 3)) * 255).astype(np.uint8))
        frame.update(mask_path=f"mask_{i}", depth_path=f"depth_{i}.npy", normal_path=f"normal_{i}.npy",
                     color_path=f"color_{i}.png", clean_path=f"color_{i}.png")
        if i == 1:
            frame["reference_path"] = f"color_{i}.png"

    aabb = [[-1, -2, -3], [1, 2, 3]]
    path = tiny_transforms(n=3, model="ORTHOGRAPHIC", frame_extra=extras, aabb=aabb,
                           reference_sets={"one": ["view_01"]})
    s = read_transforms(path)
    assert s.train.cameras.model == "orthographic"
    assert s.train.masks.dtype == torch.bool and s.train.masks[0].sum() == 36 and s.train.masks[0, 2, 3]
    np.testing.assert_allclose(s.train.depths[2].numpy(), np.load(root / "depth_2.npy"))
    assert s.train.normals.shape == (3, 12, 16, 3) and s.train.colors.shape == (3, 12, 16, 3)
    bgr = cv2.imread(str(root / "color_1.png"))
    np.testing.assert_allclose(s.references["view_01"].numpy(), bgr[..., ::-1] / 255.0, atol=1e-6)
    assert list(s.references) == ["view_01"] and s.reference_sets == {"one": ["view_01"]}
    np.testing.assert_allclose(s.bounds.numpy(), aabb)
    assert s.specimen_size is None and s.scale == (pytest.approx(np.sqrt(56)), "bounding-box diagonal")


def test_specimen_size_sets_the_length_scale_of_depth_errors(tiny_transforms):
    path = tiny_transforms(n=3)
    meta = json.loads(path.read_text())
    meta["synthetic"] = {"grain_size": 2.0}  # what the built-in generator writes
    path.write_text(json.dumps(meta))
    assert read_transforms(path).scale == (2.0, "specimen diameter")
    meta["specimen_size"] = 0.5  # a user's own dataset states it directly (it wins)
    path.write_text(json.dumps(meta))
    assert read_transforms(path).scale == (0.5, "specimen diameter")
    meta["specimen_size"] = -1
    path.write_text(json.dumps(meta))
    with pytest.raises(DataError, match="transforms.json.*'specimen_size' must be a positive finite number"):
        read_transforms(path)


def test_rgba_and_point_cloud(tiny_transforms, tmp_path):
    path = tiny_transforms(n=2)
    rgba = np.zeros((12, 16, 4), np.uint8)
    rgba[..., 2], rgba[:6, :, 3] = 200, 255  # red (BGR order) on the top half only
    cv2.imwrite(str(path.parent / "view_00.png"), rgba)
    cv2.imwrite(str(path.parent / "view_01.png"), rgba)
    pts = np.array([[0, 0, 0], [1, 2, 3], [-1, 0.5, 2]], np.float32)
    write_ply(path.parent / "points.ply", pts, np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
    meta = json.loads(path.read_text())
    meta["ply_file_path"] = "points.ply"
    path.write_text(json.dumps(meta))
    s = read_transforms(path)
    np.testing.assert_allclose(s.train.images[0, 0, 0].numpy(), [200 / 255, 0, 0], atol=1e-6)
    assert s.train.images[0, 11, 0].abs().sum() == 0  # transparent -> black background
    assert s.train.masks[0, :6].all() and not s.train.masks[0, 6:].any()
    np.testing.assert_allclose(s.points.numpy(), pts)
    np.testing.assert_allclose(s.point_colors.numpy(), np.eye(3))
    assert (s.bounds[0] <= torch.tensor([-1.0, 0, 0])).all() and (s.bounds[1] >= torch.tensor([1.0, 2, 3])).all()


def test_bounds_from_cameras_contain_target(tiny_transforms):
    s = read_transforms(tiny_transforms(n=4))
    assert (s.bounds[0] < 0).all() and (s.bounds[1] > 0).all()
    assert s.bounds[1, 0] - s.bounds[0, 0] < 8  # a few units, not the whole camera ring


def test_ascii_ply(tmp_path):
    p = tmp_path / "a.ply"
    p.write_text("ply\nformat ascii 1.0\ncomment hi\nelement vertex 2\nproperty float x\nproperty float y\n"
                 "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                 "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
                 "1 2 3 255 0 51\n4 5 6 0 255 0\n")
    pts, col = read_ply(p)
    np.testing.assert_allclose(pts, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(col, [[1, 0, 0.2], [0, 1, 0]])


@pytest.mark.parametrize("errcase", ["size", "mixed", "missing", "distortion", "refset"])
def test_reader_errors_name_the_file(tiny_transforms, errcase):
    path = tiny_transforms(n=3)
    meta = json.loads(path.read_text())
    if errcase == "size":
        cv2.imwrite(str(path.parent / "view_01.png"), np.zeros((10, 16), np.uint8))
        match = "view_01.png is 16x10 but its camera is 16x12"
    elif errcase == "mixed":
        meta["frames"][2].update(w=20)
        match = "view_02.*all views must share one size"
    elif errcase == "missing":
        meta["frames"][1]["file_path"] = "nope.png"
        match = "frame 1.*nope.png"
    elif errcase == "distortion":
        meta["k4"] = 0.1  # a fisheye's (k1, k2, k3, p1, p2 are undistorted as read)
        match = r"lens distortion \(k4\) of a fisheye camera is not supported"
    else:
        meta["reference_sets"] = {"five": ["view_00", "ghost"]}
        match = "reference set 'five'.*ghost"
    path.write_text(json.dumps(meta))
    with pytest.raises(DataError, match=match):
        read_transforms(path)


# ------------------------------------------------------------------ COLMAP
def write_colmap(root, w2cs, K, w, h, model="PINHOLE", params=None, text=False, points=None):
    import pycolmap

    rec = pycolmap.Reconstruction()
    params = params if params is not None else [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=w, height=h, params=params, camera_id=1))
    for i, w2c in enumerate(w2cs):
        img = pycolmap.Image(name=f"view_{i:02d}.png", camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.ascontiguousarray(w2c[:3, :4])))
    for xyz, rgb in points or []:
        rec.add_point3D(np.asarray(xyz, float), pycolmap.Track(), np.asarray(rgb, np.uint8))
    model_dir = root / "sparse" / "0"
    model_dir.mkdir(parents=True)
    rec.write_text(str(model_dir)) if text else rec.write(str(model_dir))
    return root


@pytest.mark.parametrize("text", [False, True])
def test_colmap_matches_transforms(tiny_transforms, tmp_path, text):
    path = tiny_transforms(n=3, w=16, h=12, fl=20.0)
    ref = read_transforms(path)
    root = tmp_path / "colmap"
    (root / "images").mkdir(parents=True)
    for i in range(3):
        (root / "images" / f"view_{i:02d}.png").write_bytes((path.parent / f"view_{i:02d}.png").read_bytes())
    K = ref.train.cameras.K[0].double().numpy()
    write_colmap(root, ring_poses(3), K, 16, 12, text=text, points=[((0.1, 0.2, 0.3), (255, 0, 51))])
    s = read_colmap(root)
    assert s.train.names == ref.train.names
    torch.testing.assert_close(s.train.cameras.world_to_cam, ref.train.cameras.world_to_cam, atol=1e-5, rtol=0)
    torch.testing.assert_close(s.train.cameras.K, ref.train.cameras.K)
    torch.testing.assert_close(s.train.images, ref.train.images)
    np.testing.assert_allclose(s.points.numpy(), [[0.1, 0.2, 0.3]], atol=1e-6)
    np.testing.assert_allclose(s.point_colors.numpy(), [[1, 0, 0.2]], atol=1e-6)
    same = load_scene({"kind": "colmap", "path": str(root), "downscale": 2})
    assert same.train.images.shape == (3, 6, 8, 3)


def test_colmap_distortion_refused_or_undistorted(tmp_path):
    root = tmp_path / "c"
    (root / "images").mkdir(parents=True)
    img = np.zeros((30, 40), np.uint8)
    img[::5, :] = 255  # horizontal lines bend under radial distortion
    for i in range(2):
        cv2.imwrite(str(root / "images" / f"view_{i:02d}.png"), img)
    K = np.array([[30.0, 0, 20], [0, 30, 15], [0, 0, 1]])
    write_colmap(root, ring_poses(2), K, 40, 30, model="SIMPLE_RADIAL", params=[30, 20, 15, 0.3])
    with pytest.raises(DataError, match="camera 1: model SIMPLE_RADIAL"):
        read_colmap(root, undistort=False)
    s = read_colmap(root, undistort=True)
    expected = cv2.undistort(img.astype(np.float32) / 255, K, np.array([0.3, 0, 0, 0]), None, K)
    np.testing.assert_allclose(s.train.images[0, ..., 0].numpy(), expected, atol=1e-6)
    assert not np.allclose(expected, img / 255.0)
    torch.testing.assert_close(s.train.cameras.K[0].double(), torch.from_numpy(K))


def test_transforms_distortion_undistorted_as_colmap_does_or_refused(tiny_transforms):
    """instant-ngp's k1, k2, p1, p2 (colmap2nerf writes an OPENCV camera so): the images are undistorted as read, with
    the same function as the COLMAP reader's, to the same K; ``undistort=False`` refuses them naming the keys."""
    path = tiny_transforms(n=3)
    img = np.zeros((12, 16), np.uint8)
    img[::3, :] = 255  # horizontal lines bend under radial distortion
    for i in range(3):
        cv2.imwrite(str(path.parent / f"view_{i:02d}.png"), img)
    plain = read_transforms(path)
    meta = json.loads(path.read_text())
    meta.update(k1=0.3, k2=-0.05, p1=0.01, p2=None)
    path.write_text(json.dumps(meta))
    with pytest.raises(DataError, match=r"frame 0 .*lens distortion \(k1, k2, p1\); set dataset.undistort=true"):
        read_transforms(path, undistort=False)
    s = read_transforms(path)
    K = s.train.cameras.K[0].double().numpy()
    expected = cv2.undistort(img.astype(np.float32) / 255, K, np.array([0.3, -0.05, 0.01, 0, 0]), None, K)
    np.testing.assert_allclose(s.train.images[0, ..., 0].numpy(), expected, atol=1e-6)
    assert not np.allclose(expected, img / 255.0)
    torch.testing.assert_close(s.train.cameras.K, plain.train.cameras.K)  # the same pinhole camera
    same = load_scene({"kind": "transforms", "path": str(path)})  # the dataset config's default: undistort
    torch.testing.assert_close(same.train.images, s.train.images)
    with pytest.raises(DataError, match="set dataset.undistort=true"):
        load_scene({"kind": "transforms", "path": str(path), "undistort": False})


def test_grey_option_on_grey_images_gives_no_colour_truth(tiny_transforms):
    """``dataset.grey=true`` on views that are grey already (an SEM series): their "colour" would score stage 2
    against grey, so there is no colour ground truth, and a warning says why; the grey images read as without it."""
    path = tiny_transforms(n=3)
    plain, grey = read_transforms(path), read_transforms(path, ReaderOptions(grey=True))
    assert grey.train.colors is None and grey.test.colors is None
    assert any("dataset.grey=true but every view is grey already" in w for w in grey.warnings)
    torch.testing.assert_close(grey.train.images, plain.train.images)
    img = cv2.imread(str(path.parent / "view_01.png"))
    img[2:6, 3:9] = (0, 0, 255)  # one view with colour content: every view's colour is its truth
    cv2.imwrite(str(path.parent / "view_01.png"), img)
    mixed = read_transforms(path, ReaderOptions(grey=True))
    assert mixed.train.colors is not None and not any("grey already" in w for w in mixed.warnings)


def test_load_scene_synthetic_dispatch(monkeypatch, tmp_path):
    import arcsem.synthetic as synth

    calls = []

    def fake_ensure_scene(**params):
        calls.append(params)
        return write_transforms_scene(tmp_path / "syn", n=2).parent

    monkeypatch.setattr(synth, "ensure_scene", fake_ensure_scene, raising=False)
    s = load_scene({"kind": "synthetic", "width": 32, "n_horizontal": 3, "downscale": 1, "split": "none"})
    assert calls == [{"width": 32, "n_horizontal": 3}] and len(s.train) == 2


def test_load_scene_config_errors(tiny_transforms):
    from omegaconf import OmegaConf

    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="dataset.path is not set"):
        load_scene(OmegaConf.create({"kind": "transforms", "path": "???"}))
    with pytest.raises(ConfigError, match="unknown kind 'nerf'; available: transforms, colmap, synthetic"):
        load_scene({"kind": "nerf"})
    with pytest.raises(ConfigError, match="dataset.split: must be one of auto, every_k, holdout, none, got 'random'"):
        load_scene({"kind": "transforms", "path": "x", "split": "random"})
    path = tiny_transforms(n=2, aabb=[[0, 0], [1, 1]])
    with pytest.raises(DataError, match="'aabb' must be"):
        load_scene({"kind": "transforms", "path": str(path)})


def test_content_box_spans_the_plenoxels_grid_and_leaves_the_gaussians_scale(tiny_transforms):
    """``content_aabb`` (arcsem-calibrate's box of all the views show) is the Plenoxels grid's; ``aabb`` stays the
    specimen's box and the Gaussians' length scale (``extent``)."""
    from arcsem.backbones.plenoxels.bounds import grid_bounds

    box, content = [[-1, -1, -1], [1, 1, 1]], [[-3, -2, -1.5], [3, 2, 1.5]]
    s = read_transforms(tiny_transforms(n=3, model="ORTHOGRAPHIC", aabb=box, content_aabb=content))
    np.testing.assert_allclose(s.bounds.numpy(), box)
    np.testing.assert_allclose(s.content_bounds.numpy(), content)
    assert s.extent == pytest.approx(1.1 * np.sqrt(12))
    np.testing.assert_allclose(grid_bounds(s).numpy(), content)
    plain = read_transforms(tiny_transforms("plain", n=3, model="ORTHOGRAPHIC", aabb=box))
    assert plain.content_bounds is None
    np.testing.assert_allclose(grid_bounds(plain).numpy(), box)
    with pytest.raises(DataError, match="'content_aabb' must be"):
        read_transforms(tiny_transforms("bad", n=2, aabb=box, content_aabb=[[0, 0], [1, 1]]))
