"""Tests of the built-in synthetic SEM scene (arcsem.synthetic)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from arcsem.cameras import Cameras
from arcsem.synthetic import cache as cache_mod
from arcsem.synthetic import ensure_scene, generate_scene
from arcsem.synthetic.sdf import body_sdf, make_grain, round_cone, smooth_min
from arcsem.synthetic.trace import sdf_gradient, sphere_trace

SMALL = {"width": 48, "height": 32}
FLIP = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return generate_scene(tmp_path_factory.mktemp("pin") / "scene", seed=0, **SMALL)


@pytest.fixture(scope="module")
def ortho_scene(tmp_path_factory) -> Path:
    return generate_scene(tmp_path_factory.mktemp("ortho") / "scene", seed=0, width=40, height=28,
                          camera="orthographic", n_horizontal=5, n_vertical=4, supersample=1)


def _cameras(meta: dict) -> Cameras:
    c2w = torch.tensor([f["transform_matrix"] for f in meta["frames"]], dtype=torch.float64) @ FLIP
    K = torch.tensor([[meta["fl_x"], 0, meta["cx"]], [0, meta["fl_y"], meta["cy"]], [0, 0, 1]], dtype=torch.float64)
    model = "pinhole" if meta["camera_model"] == "PINHOLE" else "orthographic"
    return Cameras(torch.linalg.inv(c2w), K.expand(len(c2w), 3, 3).clone(), meta["w"], meta["h"], model)


def _load(path: Path):
    meta = json.loads(path.read_text())
    root = path.parent
    depth = torch.stack([torch.from_numpy(np.load(root / f["depth_path"])).double() for f in meta["frames"]])
    mask = torch.stack([torch.from_numpy(np.array(Image.open(root / f["mask_path"]))) for f in meta["frames"]])
    return meta, depth, mask


# ---------------------------------------------------------------- geometry primitives (hand values)
def test_round_cone_hand_values():
    a, b = torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    r0, r1 = 0.2, 0.2  # equal radii: a capsule
    p = torch.tensor([[0.0, 0.0, 2.0], [0.5, 0.0, 0.5], [0.0, 0.0, -0.5], [0.0, 0.0, 0.5]], dtype=torch.float64)
    d = round_cone(p, a, b, r0, r1)
    torch.testing.assert_close(d, torch.tensor([0.8, 0.3, 0.3, -0.2], dtype=torch.float64))
    # a true cone: tip sphere radius 0, base radius 0.3, length 1: beyond the tip, distance to the tip point
    d = round_cone(torch.tensor([[0.0, 0.0, 1.5]], dtype=torch.float64), a, b, 0.3, 0.0)
    torch.testing.assert_close(d, torch.tensor([0.5], dtype=torch.float64))


def test_smooth_min_is_min_beyond_blend_and_below_inside():
    a = torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64)
    b = torch.tensor([0.5, 0.01, 0.1], dtype=torch.float64)
    s = smooth_min(a, b, 0.04)
    assert s[0] == 0.0                      # |a - b| >= k: exactly min
    assert s[1] < 0.0 and s[2] < 0.1        # within the blend: below min
    torch.testing.assert_close(s[2], torch.tensor(0.1 - 0.01, dtype=torch.float64))  # h = 0.5: min - k/4


def test_sphere_trace_hits_a_sphere_at_the_analytic_distance():
    sdf = lambda p: p.norm(dim=-1) - 1.0
    o = torch.tensor([[0.0, 0.0, -3.0], [0.5, 0.0, -3.0], [2.0, 0.0, -3.0]], dtype=torch.float64)
    u = torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=torch.float64)
    t, hit = sphere_trace(sdf, o, u, torch.full((3,), 10.0, dtype=torch.float64), eps=1e-9, tol=1e-8)
    assert hit.tolist() == [True, True, False]
    torch.testing.assert_close(t[:2], torch.tensor([2.0, 3.0 - math.sqrt(0.75)], dtype=torch.float64))
    n, lap = sdf_gradient(sdf, o[:1] + t[:1, None] * u[:1], h=1e-4)
    torch.testing.assert_close(n, torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64), atol=1e-6, rtol=0)
    assert abs(lap.item() - 2.0) < 1e-2     # Laplacian of |p| - 1 on the unit sphere: 2 / r


def test_grain_sdf_equals_dense_union_of_all_spines_near_the_surface():
    g = make_grain(3)
    gen = torch.Generator().manual_seed(0)
    p = torch.randn(50_000, 3, generator=gen, dtype=torch.float64)
    p = p / p.norm(dim=-1, keepdim=True) * (0.6 + torch.rand(50_000, 1, generator=gen, dtype=torch.float64) * 0.9)
    d = g.sdf(p)
    dense = body_sdf(g, p)
    tips = g.spine_base + g.spine_axis * g.spine_len[:, None]
    cones = round_cone(p[:, None], (g.spine_base - g.spine_axis * 0.03)[None], tips[None], g.spine_r0, g.spine_r1)
    for j in range(cones.shape[1]):
        dense = smooth_min(dense, cones[:, j], g.blend)
    near = dense.abs() < 0.02
    assert near.sum() > 1000
    torch.testing.assert_close(d[near], dense[near], atol=1e-9, rtol=0)
    assert (d - dense).max() < 1e-3         # a lower bound elsewhere (safe sphere-tracing steps)
    assert 20 <= len(g.spine_len) <= 40


def test_grey_is_a_smooth_function_of_the_surface_point():
    """Clean images hold no sub-pixel noise: moving a hit point 1e-5 along the surface (1/2000 px at
    192 px) changes its grey by < 2e-3. (A float32 curvature stencil once varied it by ~0.1.)"""
    from arcsem.synthetic import render as R
    from arcsem.synthetic.cameras import arc_cameras, arc_views

    g = make_grain(0)
    cams, _ = arc_cameras(arc_views()[:1], 64, 48)
    rays = R.view_rays(cams, [cams.pixel_grid(torch.float64).reshape(-1, 2)])
    kind, t = R.cast(g.to(torch.float32), rays["o"], rays["u"], R.RenderConfig())
    on = kind == R.GRAIN
    pts = rays["o"][on] + t[on, None] * rays["u"][on]
    n, _ = sdf_gradient(g.sdf, pts)
    tangent = torch.nn.functional.normalize(torch.linalg.cross(n, torch.randn_like(n)), dim=-1)
    moved = pts + 1e-5 * tangent
    args = (rays["u"][on], rays["det"][on], R.RenderConfig())
    a = R.shade(g.to(torch.float32), kind[on], pts, *args)["grey"]
    b = R.shade(g.to(torch.float32), kind[on], moved, *args)["grey"]
    assert on.sum() > 300
    assert (a - b).abs().max() < 2e-3, f"max grey change {(a - b).abs().max():.3f}"


# ---------------------------------------------------------------- the written dataset
@pytest.mark.parametrize("which", ["scene", "ortho_scene"])
def test_depth_agrees_with_sdf(which, request):
    path = request.getfixturevalue(which)
    meta, depth, mask = _load(path)
    cams = _cameras(meta)
    pts = cams.unproject(depth)
    g = make_grain(meta["synthetic"]["seed"], meta["synthetic"]["n_spines"])
    on = mask > 0
    assert on.sum() > 100
    err = g.sdf(pts[on]).abs()
    assert err.max() < 1e-3 * g.size, f"max |SDF| {err.max():.2e}"
    # and points off the specimen are not on it
    normals = torch.stack([torch.from_numpy(np.load(path.parent / f["normal_path"])) for f in meta["frames"]])
    assert torch.allclose(normals[on].norm(dim=-1).double(), torch.ones(int(on.sum()), dtype=torch.float64), atol=1e-4)
    assert (normals[~on] == 0).all()


def test_masks_match_depth(scene):
    _meta, depth, mask = _load(scene)
    assert set(np.unique(mask.numpy())) <= {0, 255}
    assert torch.equal(mask == 255, depth > 0)
    frac = (mask > 0).double().mean((1, 2))
    assert (frac > 0.1).all() and (frac < 0.7).all()


def test_five_reference_views_are_the_papers(scene):
    meta = json.loads(scene.read_text())
    cams = _cameras(meta)
    centres = cams.centers
    az = torch.rad2deg(torch.atan2(centres[:, 0], -centres[:, 1]))
    el = torch.rad2deg(torch.asin(centres[:, 2] / centres.norm(dim=-1)))
    names = [f["file_path"].split("/")[-1][:-4] for f in meta["frames"]]
    train = [f["split"] == "train" for f in meta["frames"]]
    horiz = [i for i in range(len(names)) if train[i] and abs(el[i] - 10) < 1e-6 and names[i].startswith("h")]
    vert = [i for i in range(len(names)) if train[i] and names[i].startswith("v")]
    assert len(horiz) == 20 and len(vert) == 12 and sum(train) == 32 and len(names) == 40
    five = meta["reference_sets"]["five"]
    left = names[min(horiz, key=lambda i: az[i])]
    right = names[max(horiz, key=lambda i: az[i])]
    centre = names[min(horiz, key=lambda i: abs(az[i]))]
    top = names[max(vert, key=lambda i: el[i])]
    assert five[:3] == [left, centre, right] and five[4] == top
    angled = names.index(five[3])
    assert angled in vert and 30 < el[angled] < 60 and abs(az[angled]) < 1e-6
    assert az[names.index(left)] == pytest.approx(-60) and el[names.index(top)] == pytest.approx(85)
    sets = meta["reference_sets"]
    assert sets["four"] == five[:4] and sets["three"] == five[:3]
    assert sets["two"] == [centre, right] and sets["one"] == [centre]
    for f in meta["frames"]:
        has_ref = "reference_path" in f
        assert has_ref == (f["file_path"].split("/")[-1][:-4] in five)
        if has_ref:  # the artist reference = ground-truth colour of that view
            ref = np.asarray(Image.open(scene.parent / f["reference_path"]))
            assert np.array_equal(ref, np.asarray(Image.open(scene.parent / f["color_path"])))


def test_left_camera_is_left_and_image_up_is_world_up(scene):
    cams = _cameras(json.loads(scene.read_text()))
    top_of_grain = torch.tensor([[0.0, 0.0, 0.7]], dtype=torch.float64)
    uv, _ = cams.project(top_of_grain)
    assert (uv[:, 0, 1] < cams.height / 2).all()    # +z appears above the image centre
    assert cams.centers[0, 0] < 0 < cams.centers[19, 0]  # h_00 on the left, h_19 on the right


def test_train_images_noisy_test_images_clean(scene):
    meta = json.loads(scene.read_text())
    root = scene.parent
    for f in meta["frames"]:
        img = np.asarray(Image.open(root / f["file_path"]))
        clean = np.asarray(Image.open(root / f["clean_path"]))
        assert img.ndim == 2 and img.dtype == np.uint8
        assert np.array_equal(img, clean) == (f["split"] == "test")


def _pngs(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.png"))}


def test_same_seed_gives_byte_identical_images(tmp_path):
    kw = {"width": 32, "height": 24, "n_horizontal": 3, "n_vertical": 3}
    a = generate_scene(tmp_path / "a", seed=5, **kw).parent
    b = generate_scene(tmp_path / "b", seed=5, **kw).parent
    c = generate_scene(tmp_path / "c", seed=6, **kw).parent
    pa, pb, pc = _pngs(a), _pngs(b), _pngs(c)
    assert len(pa) > 10 and pa == pb
    assert pa.keys() == pc.keys() and pa["images/h_00.png"] != pc["images/h_00.png"]


def test_ensure_scene_reuses_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ARCSEM_CACHE", str(tmp_path / "cache"))
    kw = {"width": 24, "height": 16, "n_horizontal": 3, "n_vertical": 3, "supersample": 1}
    first = ensure_scene(**kw)
    assert first.parent.parent == tmp_path / "cache" / "scenes" and (first.parent / ".complete").is_file()
    stamp = {p: p.stat().st_mtime_ns for p in first.parent.rglob("*")}

    def boom(*a, **k):
        raise AssertionError("generate_scene called although the scene is cached")

    monkeypatch.setattr(cache_mod, "generate_scene", boom)
    assert ensure_scene(**kw) == first
    assert {p: p.stat().st_mtime_ns for p in first.parent.rglob("*")} == stamp
    assert not list((tmp_path / "cache" / "scenes").glob(".*tmp*"))
    other = cache_mod.scene_key(cache_mod.SceneParams(**{**kw, "seed": 1}))
    assert other != first.parent.name         # different parameters, different folder


def test_colmap_model_reads_back_with_the_same_cameras(scene):
    pycolmap = pytest.importorskip("pycolmap")
    meta = json.loads(scene.read_text())
    rec = pycolmap.Reconstruction(str(scene.parent / "colmap" / "sparse" / "0"))
    cam = rec.cameras[1]
    assert (cam.width, cam.height) == (meta["w"], meta["h"])
    np.testing.assert_allclose(cam.params, [meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]])
    assert rec.num_images() == len(meta["frames"]) and rec.num_points3D() > 1000
    w2c = torch.linalg.inv(_cameras(meta).cam_to_world).numpy()
    by_name = {im.name: im for im in rec.images.values()}
    for i, f in enumerate(meta["frames"]):
        m = by_name[f["file_path"]].cam_from_world().matrix()
        np.testing.assert_allclose(m, w2c[i, :3], atol=1e-6)


def test_orthographic_scene_has_no_colmap_and_says_so(ortho_scene):
    root = ortho_scene.parent
    assert not (root / "colmap").exists()
    assert "orthographic" in (root / "README.txt").read_text()
    assert json.loads(ortho_scene.read_text())["camera_model"] == "ORTHOGRAPHIC"


def test_point_cloud_and_contact_sheet(scene):
    from arcsem.data import read_ply

    root = scene.parent
    meta = json.loads(scene.read_text())
    out = read_ply(root / meta["ply_file_path"])
    pts = out[0] if isinstance(out, tuple) else out
    pts = torch.as_tensor(np.asarray(pts), dtype=torch.float64)
    g = make_grain(0)
    assert len(pts) > 1000 and g.sdf(pts).abs().max() < 1e-3 * g.size
    sheet = Image.open(root / "contact_sheet.png")
    assert sheet.mode == "RGB" and sheet.width >= 8 * 48 and sheet.height >= 5 * 32


def test_orthographic_cameras_have_the_pinhole_pixel_footprint():
    from arcsem.synthetic.cameras import PAPER_FOCAL, PAPER_WIDTH, arc_cameras, arc_views

    views = arc_views()
    pin, dist = arc_cameras(views, 3072, 2048, "pinhole")
    ortho, _ = arc_cameras(views, 3072, 2048, "orthographic")
    assert pin.K[0, 0, 0].item() == PAPER_FOCAL and PAPER_WIDTH == 3072      # the paper's focal length
    torch.testing.assert_close(ortho.K[0, 0, 0], pin.K[0, 0, 0] / dist)      # pixels per unit at the origin
    assert dist > 20 * 2.0                                                    # far away: near-orthographic
    edge = torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], dtype=torch.float64)
    uv_p, _ = pin[10].project(edge)
    uv_o, _ = ortho[10].project(edge)
    torch.testing.assert_close(uv_p, uv_o, atol=0.02 * 2048, rtol=0)          # same footprint (~1% perspective)


def test_drift_is_affine_and_noise_is_added():
    from arcsem.synthetic.shading import drift_and_noise

    grey = np.linspace(0.2, 0.6, 48).reshape(6, 8)
    out = drift_and_noise(grey, np.random.default_rng(0), 0.1, 0.0, 0.0)
    A = np.stack([grey.ravel(), np.ones(grey.size)], 1)
    coef, *_ = np.linalg.lstsq(A, out.ravel(), rcond=None)
    assert np.allclose(A @ coef, out.ravel(), atol=1e-12) and not np.allclose(coef, [1, 0])
    noisy = drift_and_noise(grey, np.random.default_rng(0), 0.1, 0.03, 0.0)
    assert 0.01 < np.std(noisy - out) < 0.05


def test_true_exposures_are_the_drift_in_the_training_images(scene):
    """``true_exposures`` recomputes each training image's (contrast, brightness): a least-squares fit of
    observed = a * clean + b over unclipped pixels recovers them (scan noise limits the fit to ~0.02 in contrast)."""
    from arcsem.synthetic.write import SceneParams, true_exposures

    meta = json.loads(scene.read_text())
    truth = true_exposures(SceneParams.from_transforms(meta))
    fitted = {}
    for f in meta["frames"]:
        if f["split"] != "train":
            continue
        obs = np.asarray(Image.open(scene.parent / f["file_path"]), dtype=np.float64).ravel() / 255
        clean = np.asarray(Image.open(scene.parent / f["clean_path"]), dtype=np.float64).ravel() / 255
        ok = (clean > 0.15) & (clean < 0.85)  # chosen on the clean image: no censoring of the noise
        A = np.stack([clean[ok], np.ones(ok.sum())], 1)
        fitted[Path(f["file_path"]).stem] = np.linalg.lstsq(A, obs[ok], rcond=None)[0]
    assert sorted(fitted) == sorted(truth)
    t = np.array([truth[n] for n in sorted(truth)])
    g = np.array([fitted[n] for n in sorted(truth)])
    err = np.abs(g - t)
    assert (err.mean(0) < [0.025, 0.008]).all() and (err.max(0) < [0.06, 0.02]).all(), err.mean(0)
    assert np.corrcoef(t[:, 0], g[:, 0])[0, 1] > 0.9 and t[:, 0].std() > 0.03  # the drift is there, and found


def test_make_scene_cli_writes_a_scene(tmp_path, capsys):
    from arcsem.cli.make_scene import main

    out = tmp_path / "cli"
    args = ["--out", str(out), "--width", "24", "--height", "16", "--n-horizontal", "3", "--n-vertical", "3",
            "--camera", "orthographic", "--supersample", "1"]
    assert main(args) == 0
    assert (out / "transforms.json").is_file() and (out / ".complete").is_file()
    assert str(out / "transforms.json") in capsys.readouterr().out
    assert main(["--out", str(tmp_path / "bad"), "--n-horizontal", "1"]) == 2
