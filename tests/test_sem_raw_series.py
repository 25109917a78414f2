"""Issue 39's first "done when": raw tilt series as microscopes write them (LZW, Deflate and JPEG-in-TIFF with Zeiss
tag 34118 or FEI tag 34682 in their real text layouts, one series stored turned by 90 degrees from the scan) calibrate
with the defaults, and the pixel size is right within 1 % in each.

The views are rendered once from the built-in scene (orthographic, textured, 200 x 140): one tilt arc of five views,
stage tilt = elevation - 90 (arcsem's convention, as in ``tests/test_calibrate_cli.py``), one world unit taken as one
micrometre, so the true pixel size is the scene's world units per pixel.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from arcsem.cli.calibrate import main
from tests.test_sem_metadata import FEI, ZEISS

W, H = 200, 140
ELEVATIONS = (32.0, 40.0, 48.0, 56.0, 64.0)
TRUE_UM = 2.5 / (0.9 * min(W, H))  # arc_cameras: the 2.5-unit grain spans 90 % of the height


@pytest.fixture(scope="module")
def rendered():
    """Five noisy uint8 renders ``[H, W]`` and the true world-to-camera rotations ``[5, 3, 3]``."""
    from arcsem.synthetic.cameras import ViewSpec, arc_cameras
    from arcsem.synthetic.render import RenderConfig, render_views
    from arcsem.synthetic.write import SceneParams, make_specimen

    grain = make_specimen(SceneParams(texture=0.6))
    views = [ViewSpec(f"v{i}", "train", "v", 0.0, e) for i, e in enumerate(ELEVATIONS)]
    cams, _ = arc_cameras(views, W, H, "orthographic")
    renders = render_views(grain, cams, RenderConfig(supersample=1, texture=0.6))
    rng = np.random.default_rng(0)
    images = [np.clip(np.round((r.grey.numpy() + rng.normal(0, 0.02, (H, W))) * 255), 0, 255).astype(np.uint8)
              for r in renders]
    return images, cams.world_to_cam[:, :3, :3].numpy()


def zeiss(tilt: float, size: tuple[int, int]) -> str:
    """A Zeiss SmartSEM block (the layout of ``tests/test_sem_metadata.ZEISS``) for a scan of ``size`` (w, h)."""
    return (ZEISS.replace("Stage at T =  -9.0", f"Stage at T =  {tilt:.1f}").replace("Stage at R = 245.8", "Stage at R = 0.0")
            .replace("Scan Rot = On", "Scan Rot = Off").replace("5.825 nm", f"{TRUE_UM * 1e3:.4f} nm")
            .replace("Width = 5.965", f"Width = {TRUE_UM * size[0]:.4f}").replace("1024 * 768", f"{size[0]} * {size[1]}"))


def fei(tilt: float, degrees: bool) -> str:
    """An FEI xT INI block: StageT in radians (most versions) or degrees (others), PixelWidth and HFW in metres."""
    t = f"{tilt:.1f}" if degrees else f"{math.radians(tilt):.8f}"
    return (FEI.replace("StageR=-2.3611\r\nStageT=0.15707963", f"StageR=0\r\nStageT={t}")
            .replace("PixelWidth=3.3724e-006", f"PixelWidth={TRUE_UM * 1e-6:.6e}")
            .replace("HFW=0.00172667", f"HFW={TRUE_UM * 1e-6 * W:.6e}").replace("ResolutionY=442", f"ResolutionY={H}"))


SERIES = {  # name: (compression, vendor tag, stored turned by 90 degrees)
    "lzw-zeiss": ("lzw", "zeiss", False),
    "deflate-fei-radians": ("adobe_deflate", "fei", False),
    "jpeg-fei-degrees": ("jpeg", "fei-deg", False),
    "jpeg-zeiss": ("jpeg", "zeiss", False),
    "lzw-zeiss-turned": ("lzw", "zeiss", True),
}


def write_raw(folder, images, compression: str, vendor: str, turned: bool) -> None:
    import tifffile

    folder.mkdir()
    for i, (img, el) in enumerate(zip(images, ELEVATIONS)):
        tilt = el - 90.0
        code, text = (34118, zeiss(tilt, (W, H))) if vendor == "zeiss" else (34682, fei(tilt, vendor == "fei-deg"))
        tifffile.imwrite(folder / f"img_{i + 1}.tif", np.ascontiguousarray(np.rot90(img)) if turned else img,
                         compression=compression, metadata=None, extratags=[(code, 2, 0, text.encode("latin-1"), True)])


def pair_angles(R: np.ndarray) -> np.ndarray:
    """Degrees between every two rotations ``R [V, 3, 3]``: blind to a world rotation and to a turned image."""
    i, j = np.triu_indices(len(R), 1)
    rel = np.einsum("nab,ncb->nac", R[i], R[j])
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SERIES))
def test_raw_series_calibrates_with_the_defaults(rendered, tmp_path, capsys, name):
    """Each series: defaults only (stage angles and pixel size from the tags); the dataset's pixel size and every
    view's scale within 1 % of the truth, the angles between views within 0.3 degrees of the true ones."""
    from arcsem.data import read_transforms

    images, true_R = rendered
    compression, vendor, turned = SERIES[name]
    write_raw(tmp_path / "raw", images, compression, vendor, turned)
    assert main([str(tmp_path / "raw"), "--out", str(tmp_path / "ds")]) == 0, capsys.readouterr().err
    meta = json.loads((tmp_path / "ds" / "transforms.json").read_text())
    assert (meta["w"], meta["h"]) == ((H, W) if turned else (W, H))
    assert meta["pixel_size_um"] == pytest.approx(TRUE_UM, rel=0.01)
    assert [f["fl_x"] * TRUE_UM for f in meta["frames"]] == pytest.approx([1.0] * len(images), rel=0.01)
    frame = meta["frames"][0]
    assert frame["intensity_levels"] == "0..255 (BitsPerSample 8)"
    assert frame["pixel_size_from"].startswith("TIFF tag 34118 'Image Pixel Size'" if "zeiss" in vendor else
                                               "TIFF tag 34682 '[Scan] PixelWidth'")
    scene = read_transforms(tmp_path / "ds")
    order = np.argsort(scene.train.names)
    got = scene.train.cameras.world_to_cam[order, :3, :3].double().numpy()
    assert np.abs(pair_angles(got) - pair_angles(true_R)).max() < 0.3
