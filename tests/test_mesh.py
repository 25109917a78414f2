"""TSDF fusion + marching cubes on analytic depth maps of a sphere (pinhole and orthographic),
component clean-up, mesh files, and the Chamfer protocol against a known surface."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from arcsem.cameras import Cameras, look_at
from arcsem.mesh.groundtruth import chamfer, sample_mesh
from arcsem.mesh.tsdf import TSDFVolume, extract_mesh, keep_components, make_grid

R = 0.6  # sphere radius, centred at the origin


def ring(model: str, n: int = 10, size: int = 128) -> Cameras:
    """``n`` cameras around the origin (azimuths all round, elevations alternating +-30 degrees)."""
    az = torch.linspace(0, 2 * math.pi, n + 1, dtype=torch.float64)[:-1]
    el = torch.tensor([0.5 if i % 2 else -0.5 for i in range(n)], dtype=torch.float64)
    eye = 4.0 * torch.stack([torch.cos(az) * torch.cos(el), torch.sin(az) * torch.cos(el), torch.sin(el)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    f = 160.0 if model == "pinhole" else 80.0  # pinhole: px per x/z; orthographic: px per unit
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]], dtype=torch.float64)
    return Cameras(w2c, K.expand(n, 3, 3).clone(), size, size, model)


def sphere_depth(cams: Cameras) -> tuple[torch.Tensor, torch.Tensor]:
    """Analytic z-depth ``[C, H, W]`` of the sphere and its hit mask (rays have unit camera z)."""
    o, d = cams.rays()
    a = (d * d).sum(-1)
    b = 2 * (o * d).sum(-1)
    c = (o * o).sum(-1) - R**2
    disc = b * b - 4 * a * c
    hit = disc > 0
    t = (-b - disc.clamp_min(0).sqrt()) / (2 * a)
    return torch.where(hit, t, torch.zeros_like(t)), hit


def fuse(model: str, voxel: float = 0.04, carve: bool = True, extra=None, impl: str = "auto",
         shaded: bool = False) -> TSDFVolume:
    cams = ring(model)
    depth, hit = sphere_depth(cams)
    bounds = torch.tensor([[-0.8] * 3, [0.8] * 3], dtype=torch.float64)
    vol = TSDFVolume(make_grid(bounds, voxel, pad=5), trunc=4 * voxel, impl=impl)
    for i in range(len(cams)):
        rgb = torch.zeros(cams.height, cams.width, 3)
        rgb[..., 0] = 1.0  # red sphere
        if shaded:  # colours that differ per view and pixel, so that the running means are tested
            rgb[..., 1] = torch.rand(cams.height, cams.width, generator=torch.Generator().manual_seed(i))
        d, h = depth[i], hit[i]
        if extra is not None:
            d, h = extra(i, d, h)
        vol.integrate(cams[i:i + 1], d, h, rgb, background=~h if carve else None)
    return vol


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_sphere_is_recovered(model):
    verts, faces, cols = extract_mesh(fuse(model))
    r = np.linalg.norm(verts, axis=1)
    assert len(faces) > 500
    assert np.abs(r - R).max() < 0.03, np.abs(r - R).max()  # 3/4 of a voxel
    assert np.abs(r - R).mean() < 0.008  # a fifth of a voxel
    # outward faces: the signed volume of the closed sphere is positive and close to 4/3 pi R^3
    tri = verts[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert vol == pytest.approx(4 / 3 * math.pi * R**3, rel=0.03)
    np.testing.assert_allclose(cols.mean(0), [1.0, 0.0, 0.0], atol=1e-4)


def _fused_or_skip():
    from arcsem import cext
    from arcsem.mesh.fused import EXTENSION

    if cext.load(EXTENSION) is None:
        pytest.skip("the fused C++ TSDF fusion did not build here (see the warning)")


def _same_volume(a: TSDFVolume, b: TSDFVolume) -> None:
    """Equal to float32 round-off, except voxels whose pixel flips at a pixel edge (FMA vs separate ops): at most
    1 in 10^4 of them."""
    for name in ("weight", "color_weight"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x != y).float().mean() < 1e-4, (name, int((x != y).sum()))
    same = (a.weight == b.weight) & (a.color_weight == b.color_weight)
    assert same.float().mean() > 0.999 and a.weight.sum() > 0 and a.color_weight.sum() > 0
    torch.testing.assert_close(a.tsdf[same], b.tsdf[same], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(a.color[same], b.color[same], atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("carve", [True, False])
def test_fused_integration_equals_the_pytorch_reference(model, carve):
    _fused_or_skip()
    ref = fuse(model, carve=carve, impl="torch", shaded=True)
    fused = fuse(model, carve=carve, impl="cpp", shaded=True)
    assert fused.fused and not ref.fused
    _same_volume(ref, fused)


def test_fused_integration_skips_voxels_behind_a_pinhole_camera():
    """A camera inside the grid (half of the voxels behind it) and one view without colour: the reference's rules."""
    _fused_or_skip()
    eye = torch.tensor([[0.0, 0.0, 0.3]], dtype=torch.float64)
    w2c = look_at(eye, torch.tensor([[0.0, 0.0, 3.0]], dtype=torch.float64),
                  torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[[40.0, 0.0, 32.0], [0.0, 40.0, 32.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    cam = Cameras(w2c, K, 64, 64, "pinhole")
    depth = torch.full((64, 64), 0.35)
    hit = torch.zeros(64, 64, dtype=torch.bool)
    hit[:, :40] = True
    bounds = torch.tensor([[-0.8] * 3, [0.8] * 3], dtype=torch.float64)
    vols = [TSDFVolume(make_grid(bounds, 0.04, pad=2), trunc=0.16, impl=impl) for impl in ("torch", "cpp")]
    for vol in vols:
        vol.integrate(cam, depth, hit, None, background=~hit)
        vol.integrate(cam, depth * 1.5, hit, torch.ones(64, 64, 3), background=None)
    _same_volume(*vols)


def test_unobserved_space_makes_no_surface():
    # only one view: the fused TSDF has a front cap, never a closed sphere nor the truncation band's back
    cams = ring("pinhole")[:1]
    depth, hit = sphere_depth(cams)
    bounds = torch.tensor([[-0.8] * 3, [0.8] * 3], dtype=torch.float64)
    vol = TSDFVolume(make_grid(bounds, 0.04, pad=5), trunc=0.16)
    vol.integrate(cams, depth[0], hit[0])
    verts, faces, _ = extract_mesh(vol)
    r = np.linalg.norm(verts, axis=1)
    assert len(faces) > 50 and np.abs(r - R).max() < 0.03
    assert (verts @ cams.forward[0].numpy() < 0.1).all()  # all of it on the side facing the camera


def test_carving_removes_a_floater_seen_by_one_view():
    def floater(i, d, h):  # view 0 sees a spurious blob 0.25 in front of the sphere
        if i == 0:
            d, h = d.clone(), h.clone()
            d[56:72, 56:72], h[56:72, 56:72] = 3.15, True
        return d, h

    carved = extract_mesh(fuse("pinhole", carve=True, extra=floater))[0]
    kept = extract_mesh(fuse("pinhole", carve=False, extra=floater))[0]
    far = lambda v: (np.linalg.norm(v, axis=1) > R + 0.1).sum()
    assert far(kept) > 0 and far(carved) == 0


def test_keep_components_drops_small_pieces():
    big = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    small = big[:3] + 5
    verts = np.concatenate([big, small])
    faces = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6]])
    cols = np.zeros((7, 3))
    v, f, _, info = keep_components(verts, faces, cols, 0.6)  # the small one has 1/2 of the big one's faces
    assert info == {"components": 2, "kept": 1, "faces_removed": 1}
    assert len(v) == 4 and f.max() == 3 and (v == big).all()
    assert len(keep_components(verts, faces, cols, 0.5)[1]) == 3


def test_make_grid_respects_the_voxel_budget():
    bounds = torch.tensor([[0.0] * 3, [1.0] * 3])
    g = make_grid(bounds, 0.01, pad=2, max_voxels=50**3)
    assert np.prod(g.shape) <= 50**3 and g.voxel > 0.01
    assert (g.origin <= 0).all() and (g.origin + (torch.tensor(g.shape) - 1) * g.voxel >= 1).all()


class Sphere:
    """A "grain" whose SDF is a sphere's (what :func:`chamfer` asks of a grain: ``sdf`` and ``size``)."""

    size = 2 * R

    def sdf(self, p):
        return p.norm(dim=-1) - R


def test_chamfer_of_a_larger_sphere():
    # a mesh sphere 0.01 larger than the ground truth: every distance is 0.01 (up to the facets)
    from skimage.measure import marching_cubes

    x = np.linspace(-0.8, 0.8, 81)
    vol = np.linalg.norm(np.stack(np.meshgrid(x, x, x, indexing="ij"), -1), axis=-1) - (R + 0.01)
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(0.02,) * 3)
    verts -= 0.8
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(50_000, 3))
    gt = R * gt / np.linalg.norm(gt, axis=1, keepdims=True)
    out = chamfer(Sphere(), verts, faces, gt[gt[:, 2] > 0], n_mesh=200_000, n_accuracy=50_000)
    assert out["accuracy"] == pytest.approx(0.01, abs=1e-3)
    assert out["completeness"] == pytest.approx(0.01, abs=1.5e-3)
    assert out["chamfer_pct"] == pytest.approx(100 * 0.01 / (2 * R), rel=0.15)
    assert out["gt_seen_points"] == int((gt[:, 2] > 0).sum())


def test_sample_mesh_is_uniform_by_area():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 5], [3, 0, 5], [0, 3, 5]], float)
    faces = np.array([[0, 1, 2], [3, 4, 5]])  # areas 0.5 and 4.5
    pts = sample_mesh(verts, faces, 20_000)
    top = np.isclose(pts[:, 2], 5)
    assert top.mean() == pytest.approx(0.9, abs=0.01)
    assert (pts[~top][:, :2].sum(1) <= 1 + 1e-9).all() and (pts[top][:, :2].sum(1) <= 3 + 1e-9).all()


def test_ground_truth_samples_are_kept_per_grain_and_settings(tmp_path, monkeypatch):
    """The built-in grain's surface samples (the same every run) are computed once per grain and settings, then read
    back equal; a damaged file is recomputed."""
    import numpy as np

    from arcsem.mesh import groundtruth
    from arcsem.synthetic.sdf import make_grain

    calls = []
    real = groundtruth.surface_samples
    monkeypatch.setattr(groundtruth, "surface_samples", lambda g, **kw: calls.append(kw) or real(g, **kw))
    kw = {"n": 500, "spacing": 0.08}
    a = groundtruth.cached_surface_samples(make_grain(0, 8), tmp_path, **kw)
    b = groundtruth.cached_surface_samples(make_grain(0, 8), tmp_path, **kw)
    assert len(calls) == 1 and np.array_equal(a, b) and a.shape == (500, 3)
    groundtruth.cached_surface_samples(make_grain(1, 8), tmp_path, **kw)  # another grain: its own file
    groundtruth.cached_surface_samples(make_grain(0, 8), tmp_path, n=400, spacing=0.08)  # other settings: too
    assert len(calls) == 3 and len(list(tmp_path.glob("surface_*.npy"))) == 3
    for path in tmp_path.glob("surface_*.npy"):
        path.write_bytes(b"damaged")
    c = groundtruth.cached_surface_samples(make_grain(0, 8), tmp_path, **kw)
    assert len(calls) == 4 and np.array_equal(a, c)
