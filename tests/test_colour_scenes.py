"""benchmarks/colour_scenes.py: a public dataset in a git mirror becomes an arcsem scene with colour references."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from arcsem.data.transforms import read_transforms

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import colour_scenes  # (the benchmarks folder is not a package)


def _ring(n: int, radius: float = 4.0, height: float = 1.0) -> list[list[list[float]]]:
    """OpenGL camera-to-world matrices of ``n`` cameras on a ring, looking at the origin."""
    out = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        c = np.array([radius * np.cos(a), radius * np.sin(a), height])
        back = c / np.linalg.norm(c)  # OpenGL: the camera looks along -z
        right = np.cross([0, 0, 1.0], back)
        right /= np.linalg.norm(right)
        m = np.eye(4)
        m[:3, :3] = np.stack([right, np.cross(back, right), back], 1)
        m[:3, 3] = c
        out.append(m.tolist())
    return out


def _mirror(tmp: Path) -> tuple[Path, str]:
    """A bare-bones git repository holding a Blender-layout dataset of 32 px RGBA renders; its commit."""
    work = tmp / "work"
    for split, n in (("train", 8), ("test", 3)):
        (work / split).mkdir(parents=True)
        frames = []
        for i, m in enumerate(_ring(n)):
            img = np.zeros((32, 32, 4), np.uint8)
            img[8:24, 8:24] = (40, 200, 30 + 20 * i, 255)  # BGRA: a green square, opaque
            cv2.imwrite(str(work / split / f"r_{i}.png"), img)
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": m})
        (work / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    git = ["git", "-C", str(work), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", "init", "-q", str(work)], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "data"], check=True)
    commit = subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
    return work / ".git", commit


def test_reference_sets_are_nested_and_spread_around_the_object():
    c2w = np.array(_ring(12))
    refs = colour_scenes.reference_sets(c2w, [f"v{i}" for i in range(12)])
    assert refs["three"] == refs["five"][:3] and refs["one"] == refs["five"][:1] and len(set(refs["five"])) == 5
    az = sorted(int(n[1:]) * 30 for n in refs["three"])  # degrees on the ring
    gaps = np.diff(az + [az[0] + 360])
    assert gaps.min() >= 90  # three views spread around, not side by side (worst case 30)


def test_a_mirrored_dataset_becomes_a_scene_arcsem_reads_with_colour_references(tmp_path):
    mirror, commit = _mirror(tmp_path)
    src = colour_scenes.Source("someone/data", commit, "", "blender", "CC-0", "a test square", held_out=True,
                               width=16, n_train=6, n_test=2)
    path = colour_scenes.write_scene("square", src, mirror, tmp_path / "scene")
    scene = read_transforms(path)
    assert len(scene.train) == 6 and len(scene.test) == 2
    assert scene.reference_sets["five"] and set(scene.reference_sets["five"]) <= set(scene.train.names)
    meta = json.loads(path.read_text())
    assert meta["source"] == {"repository": "https://github.com/someone/data", "commit": commit, "path": ".",
                              "licence": "CC-0", "held_out": True}
    assert "Held out" in (path.parent / "SOURCE.md").read_text() and commit in (path.parent / "SOURCE.md").read_text()
    f = meta["frames"][0]
    grey = cv2.imread(str(path.parent / f["file_path"]), cv2.IMREAD_UNCHANGED)
    rgb = cv2.imread(str(path.parent / f["color_path"]))[..., ::-1].astype(float)
    mask = cv2.imread(str(path.parent / f["mask_path"]), cv2.IMREAD_UNCHANGED) > 0
    assert grey.shape == (16, 16) and mask[8, 8] and not mask[0, 0]
    assert abs(float(grey[8, 8]) - float(rgb[8, 8] @ colour_scenes.LUMA)) <= 1  # the grey is the luminance
    assert rgb[8, 8, 1] > 150 and rgb[8, 8, 0] < 60  # the colour is kept: green
    assert f["fl_x"] == pytest.approx(0.5 * 16 / np.tan(0.5 * 0.69))  # intrinsics at the written size


def test_a_missing_mirror_is_one_error_line_that_says_how_to_make_it(tmp_path, capsys):
    assert colour_scenes.main(["--only", "chair", "--mirror", f"chair={tmp_path}/none", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: --mirror chair: no git repository at {tmp_path}/none") and "\n" not in err
    assert f"git clone --bare https://github.com/{colour_scenes.DATASETS['chair'].repo}" in err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_dataset_grey_reads_the_raw_colour_dataset_as_the_written_scene(tmp_path):
    """``dataset.grey=true`` on the raw renders gives what colour_scenes.py writes: the luminance as the grey input,
    the colour as ground truth, masks from alpha; without it the colour is the input (and a warning says so)."""
    from arcsem.configs import ReaderOptions

    mirror, commit = _mirror(tmp_path)
    src = colour_scenes.Source("someone/data", commit, "", "blender", "CC-0", "a test square", width=16, n_train=8,
                               n_test=3)
    written = read_transforms(colour_scenes.write_scene("square", src, mirror, tmp_path / "scene"))
    raw = mirror.parent
    grey = read_transforms(raw, ReaderOptions(downscale=2.0, grey=True))
    as_is = read_transforms(raw, ReaderOptions(downscale=2.0))
    for split in ("train", "test"):
        a, b = getattr(grey, split), getattr(written, split)
        assert len(a) == len(b) == {"train": 8, "test": 3}[split]  # the same views in the same order
        assert (a.images - b.images).abs().max() <= 2 / 255  # 8-bit rounding of the written files
        assert (a.colors - b.colors).abs().max() <= 2 / 255 and a.colors[:, 8, 8, 1].min() > 0.6  # green kept
        assert torch.equal(a.masks, b.masks)
        assert torch.allclose(a.images[..., 0], a.images[..., 2])  # grey: one value in every channel
    assert as_is.train.colors is None and as_is.train.images[0, 8, 8, 1] > 0.6  # the colour itself is the input
    assert any("colour content" in w for w in as_is.warnings) and not any("colour content" in w for w in grey.warnings)
