"""``arcsem-calibrate``: bad input ends with one ``error:`` line naming the file and exit code 2; a tiny
textured synthetic scene calibrates end to end into a dataset arcsem and pycolmap read."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from arcsem.cli.calibrate import main
from tests.test_sem_series import sem_like, write_series


def run(capsys, *args) -> tuple[int, str]:
    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip().splitlines()
    return code, (err[-1] if err else "")


def test_single_image(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=1)
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0")
    assert code == 2 and err.startswith("error: ") and "img_1.png: a single image" in err


def test_mixed_sizes(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)
    cv2.imwrite(str(folder / "img_9.png"), sem_like(90, 160))
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,1,2,3")
    assert code == 2 and "img_9.png: image is 160x90 but img_1.png is 160x120" in err


def test_wrong_tilt_count(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,5")
    assert code == 2 and "--tilts has 2 value(s)" in err and "3 images" in err


def test_no_metadata_without_tilts(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)
    code, err = run(capsys, folder, "--out", tmp_path / "out")
    assert code == 2 and "img_1.png: no stage tilt" in err and "--tilts" in err


def test_unreadable_metadata_without_tilts(tmp_path, capsys):
    import tifffile

    folder = tmp_path / "in"
    folder.mkdir()
    text = "AP_STAGE_AT_T\r\nStage at T = ### \r\nAP_STAGE_AT_R\r\nStage at R = n/a\r\n"  # Zeiss block, garbled
    for i in range(3):
        tifffile.imwrite(folder / f"z_{i}.tif", sem_like(seed=i), metadata=None,
                         extratags=[(34118, 2, 0, text.encode("latin-1"), True)])
    code, err = run(capsys, folder, "--out", tmp_path / "out")
    assert code == 2 and "z_0.tif: no stage tilt (TIFF tag 34118 gives none readable)" in err and "--tilts" in err


def listing(folder) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_images_that_do_not_overlap(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)  # three unrelated noise textures
    before = listing(folder)
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,3,6")
    assert code == 2 and "img_" in err and "the images do not overlap" in err
    assert not (tmp_path / "out" / "transforms.json").exists() and listing(folder) == before


def test_output_folder_checks(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)
    before = listing(folder)
    code, err = run(capsys, folder, "--out", folder / "dataset", "--tilts", "0,3,6")
    assert code == 2 and "must not be written into the input folder" in err
    code, err = run(capsys, folder, "--out", tmp_path, "--tilts", "0,3,6")   # the input inside the output
    assert code == 2 and "must not be written into the input folder" in err
    assert listing(folder) == before and not (folder / "dataset").exists()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "transforms.json").write_text("{}")
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,3,6")
    assert code == 2 and "already holds a dataset" in err and "--overwrite" in err
    assert (tmp_path / "out" / "transforms.json").read_text() == "{}"         # the refused dataset is kept


def test_inspect_prints_the_table(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=2, bar=10)
    assert main([str(folder), "--inspect"]) == 0
    out = capsys.readouterr().out
    assert "img_2.png" in out and "no tilt, rotation, pixel size" in out and "data bar: 10 rows" in out


def test_focal_length_checks(tmp_path, capsys):
    folder = write_series(tmp_path / "in", n=3)
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,3,6", "--focal-px", "5000")
    assert code == 2 and err == "error: --focal-px 5000: a focal length is for --camera perspective only"
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "0,3,6", "--camera", "perspective",
                    "--focal-px", "-3")
    assert code == 2 and "--focal-px -3: must be a positive number of pixels" in err
    assert not (tmp_path / "out").exists()


def tiny(root, camera):
    from arcsem.synthetic import generate_scene

    generate_scene(root, width=240, height=160, camera=camera, texture=0.6, n_horizontal=13, n_vertical=8,
                   test_every=6, supersample=1, progress=False)
    return root


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return tiny(tmp_path_factory.mktemp("scene"), "orthographic")


def calibrate_tiny(scene, tmp_path, capsys, *flags):
    """Calibrate the tiny scene's images with its true stage angles; returns (calibrated, true) scenes."""
    from arcsem.data import read_transforms

    meta = json.loads((scene / "transforms.json").read_text())
    folder = tmp_path / "raw"
    folder.mkdir()
    rows = ["file,tilt,rotation"]
    for f in meta["frames"]:
        shutil.copy(scene / f["file_path"], folder)
        rows.append(f"{f['file_path'].split('/')[-1]},{f['elevation'] - 90},{-f['azimuth']}")
    (tmp_path / "tilts.csv").write_text("\n".join(rows))
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    px = 2.5 / (0.9 * 160)  # the scene's world units per pixel
    code = main([str(folder), "--out", str(tmp_path / "ds"), "--tilts", str(tmp_path / "tilts.csv"),
                 "--holdout", "test_*", "--pixel-size", str(px), *flags])
    assert code == 0, capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before          # the input is never written
    return read_transforms(tmp_path / "ds"), read_transforms(scene)


def rotation_errors(truth, scene) -> np.ndarray:
    """Degrees between calibrated and true rotations after one world rotation."""
    def rot(s):
        return {n: s.train.cameras.world_to_cam[i, :3, :3].double().numpy() for i, n in enumerate(s.train.names)}
    a, b = rot(truth), rot(scene)
    Rt, Rc = np.stack([a[n] for n in sorted(a)]), np.stack([b[n] for n in sorted(a)])
    U, _, Vt = np.linalg.svd(np.einsum("nji,njk->ik", Rc, Rt))
    E = np.einsum("nij,jk,nlk->nil", Rc, U @ Vt, Rt)
    return np.degrees(np.arccos(np.clip((np.trace(E, axis1=1, axis2=2) - 1) / 2, -1, 1)))


@pytest.mark.slow
def test_tiny_scene_end_to_end(tiny_scene, tmp_path, capsys):
    import pycolmap

    scene, truth = calibrate_tiny(tiny_scene, tmp_path, capsys)
    report = json.loads((tmp_path / "ds" / "report" / "calibration.json").read_text())
    assert report["rms_px"] < 0.5
    assert scene.train.cameras.is_ortho and len(scene.test) == len(truth.test) > 0
    assert scene.micrometres_per_unit == pytest.approx(1.0) and scene.train.masks is not None
    assert rotation_errors(truth, scene).max() < 0.5
    rec = pycolmap.Reconstruction(str(tmp_path / "ds" / "sparse" / "0"))
    assert rec.num_images() == len(scene.train) + len(scene.test)
    assert rec.num_points3D() == report["tracks"] and len(scene.points) > rec.num_points3D()  # + the dense start
    _dense_start_lies_on_the_surface(tiny_scene, tmp_path / "ds", report)
    for name in ("residuals.png", "report.md"):
        assert (tmp_path / "ds" / "report" / name).is_file()
    assert len(list((tmp_path / "ds" / "report").glob("overlay_*.png"))) == 2
    assert len(list((tmp_path / "ds" / "report").glob("masks_*.png"))) == 2  # the masks and their seed points
    meta = json.loads((tmp_path / "ds" / "transforms.json").read_text())  # the specimen's box inside the content's
    box, content = np.array(meta["aabb"]), np.array(meta["content_aabb"])
    assert (content[0] <= box[0]).all() and (content[1] >= box[1]).all() and (content[1] - content[0] > box[1] - box[0]).any()
    assert report["masks"]["specimen_points"] > 0 and "Masks: seeded by" in (
        tmp_path / "ds" / "report" / "report.md").read_text()


def _dense_start_lies_on_the_surface(truth, calibrated, report: dict) -> None:
    """The dense start (arcsem.calib.dense) holds several times the adjustment's points, and they lie on the true
    surface as closely as the adjustment's own (both carried into the true frame by the similarity between the two
    camera sets, benchmarks/calib_training.frame_similarity)."""
    from scipy.spatial import cKDTree

    from arcsem.ply import read_points
    from tests.test_calib_benchmark import _bench

    s, Q, d = _bench().frame_similarity(truth, calibrated)
    X = (read_points(calibrated / "points3d.ply")[0] - d) @ Q / s        # calibrated -> true frame
    n_sparse = report["tracks"]
    assert report["dense"]["points"] == len(X) - n_sparse >= 3 * n_sparse
    tree = cKDTree(read_points(truth / "points3d.ply")[0])
    sparse, dense = tree.query(X[:n_sparse])[0], tree.query(X[n_sparse:])[0]
    px = 2.5 / (0.9 * 160)  # world units per pixel
    print("distance to the surface, median / 90th percentile, sparse:", np.percentile(sparse, [50, 90]),
          "dense:", np.percentile(dense, [50, 90]), "world units per pixel:", px)
    assert np.median(dense) < max(1.5 * np.median(sparse), px), (np.median(sparse), np.median(dense))
    assert np.percentile(dense, 90) < max(2 * np.percentile(sparse, 90), 4 * px)


@pytest.mark.slow
def test_tiny_far_pinhole_scene_calibrates_as_a_pinhole(tmp_path_factory, tmp_path, capsys):
    import pycolmap

    focal = 50_000.0 * 240 / 3072                              # the scene's far pinhole (the paper's, scaled)
    root = tiny(tmp_path_factory.mktemp("pinhole"), "pinhole")
    scene, truth = calibrate_tiny(root, tmp_path, capsys, "--camera", "perspective", "--focal-px", str(focal))
    meta = json.loads((tmp_path / "ds" / "transforms.json").read_text())
    assert meta["camera_model"] == "PINHOLE" and not scene.train.cameras.is_ortho
    assert scene.train.cameras.K[0, 0, 0].item() == pytest.approx(focal)
    assert rotation_errors(truth, scene).max() < 0.5
    report = json.loads((tmp_path / "ds" / "report" / "calibration.json").read_text())
    assert report["rms_px"] < 0.5 and report["bundle"]["perspective"]["focal_px"] == pytest.approx(focal)
    assert "Camera: perspective (pinhole), focal length" in (tmp_path / "ds" / "report" / "report.md").read_text()
    rec = pycolmap.Reconstruction(str(tmp_path / "ds" / "sparse" / "0"))
    cam = next(iter(rec.cameras.values()))
    assert cam.params[0] == pytest.approx(focal)
    # the COLMAP model and transforms.json hold the same cameras: its points project alike through both
    img = next(im for im in rec.images.values() if im.name == "h_00.png")
    w2c = scene.train.cameras.world_to_cam[scene.train.names.index("h_00")].double().numpy()
    np.testing.assert_allclose(img.cam_from_world().matrix(), w2c[:3], atol=1e-6)


def test_negative_tilts_as_the_readme_writes_them(tmp_path, capsys):
    """``--tilts -9,0,9`` (a value that starts with '-'): argparse read it as an option and stopped with a usage
    message; it is the list of tilts (here one too few, so the run stops at the count, past argparse)."""
    folder = write_series(tmp_path / "in", n=3)
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "-9,0")
    assert code == 2 and "--tilts has 2 value(s)" in err
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "-9,-0.5,9", "--inspect")
    assert code == 0


def zeiss_series(folder, n=3, **replace):
    """``n`` 160x120 TIFFs with a Zeiss tag (tilts -3, 0, 3...); ``replace``: {old text: new text} in the tag."""
    import tifffile

    from tests.test_sem_metadata import ZEISS

    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        text = ZEISS.replace("Stage at T =  -9.0", f"Stage at T =  {3.0 * (i - 1)}")
        for old, new in replace.items():
            text = text.replace(old, new)
        tifffile.imwrite(folder / f"z_{i}.tif", sem_like(seed=i), metadata=None,
                         extratags=[(34118, 2, 0, text.encode("latin-1"), True)])
    return folder


def test_unphysical_metadata_ends_with_one_error_line(tmp_path, capsys):
    """A Zeiss tag whose tilts are x100 and whose pixel size is negative: the run went on and wrote a negative focal
    length (which arcsem then refused); now one error line names the file and the key, exit 2, nothing written."""
    folder = zeiss_series(tmp_path / "in", **{"Stage at T =  -3.0": "Stage at T =  -300.0",
                                              "Image Pixel Size = 5.825 nm": "Image Pixel Size = -5.825 nm"})
    code, err = run(capsys, folder, "--out", tmp_path / "out")
    assert code == 2 and err.startswith("error: ") and "z_0.tif: TIFF tag 34118 (Zeiss) 'Stage at T = -300.0" in err
    assert "give --tilts" in err and not (tmp_path / "out").exists()
    code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "-3,0,3")
    assert code == 2 and "z_0.tif: TIFF tag 34118 (Zeiss) 'Image Pixel Size = -5.825 nm'" in err
    for bad in ("-1", "0", "inf", "nan"):
        code, err = run(capsys, folder, "--out", tmp_path / "out", "--tilts", "-3,0,3", "--pixel-size", bad)
        assert code == 2 and f"error: --pixel-size {bad}: must be a positive number of micrometres" == err
    assert not (tmp_path / "out").exists()


def test_inspect_says_where_each_number_comes_from(tmp_path, capsys):
    folder = zeiss_series(tmp_path / "in")
    assert main([str(folder), "--inspect"]) == 0
    out = capsys.readouterr().out.split("where the numbers come from:")[1]
    for line in ("tilt: TIFF tag 34118 'Stage at T' (every image)", "rot: TIFF tag 34118 'Stage at R' (every image)",
                 "pixel: TIFF tag 34118 'Image Pixel Size' x 1024 / 160 px (every image)",
                 "levels: 0..255 (BitsPerSample 8) (every image)", "WD: TIFF tag 34118 'WD' (every image)",
                 "orient: as stored (every image)"):
        assert line in out
    csv = tmp_path / "t.csv"
    csv.write_text("z_0.tif,-3,10\nz_1.tif,0\nz_2.tif,3\n")
    assert main([str(folder), "--inspect", "--tilts", str(csv), "--pixel-size", "0.01"]) == 0
    out = capsys.readouterr().out.split("where the numbers come from:")[1]
    assert "tilt: --tilts t.csv (every image)" in out and "pixel: --pixel-size (every image)" in out
    assert "rot: --tilts t.csv (z_0.tif); TIFF tag 34118 'Stage at R' (z_1.tif, z_2.tif)" in out
    png = write_series(tmp_path / "png", n=2)
    assert main([str(png), "--inspect", "--tilts", "0,3"]) == 0
    out = capsys.readouterr().out.split("where the numbers come from:")[1]
    assert "rot: default 0 (none given) (every image)" in out and "levels: 0..255 (8-bit samples)" in out
    assert "pixel: none (every image)" in out
