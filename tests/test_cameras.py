"""Cameras: projection/unprojection round trips, pinhole -> orthographic limit, rays, conventions."""
from __future__ import annotations

import pytest
import torch

from arcsem.cameras import Cameras, look_at, opengl_to_opencv

DT = torch.float64


def make_cams(model: str, dist: float = 4.0, f: float = 30.0, w: int = 20, h: int = 14) -> Cameras:
    ang = torch.tensor([-0.5, 0.1, 0.7], dtype=DT)
    eye = torch.stack([torch.sin(ang), torch.tensor([0.3, -0.2, 0.5], dtype=DT), -torch.cos(ang)], -1)
    eye = dist * torch.nn.functional.normalize(eye, dim=-1)  # same directions at every distance
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=DT))
    K = torch.tensor([[f, 0.0, w / 2 + 0.3], [0.0, f * 1.2, h / 2 - 0.4], [0, 0, 1]], dtype=DT).repeat(3, 1, 1)
    return Cameras(w2c, K, w, h, model)


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_project_after_unproject_is_identity(model):
    cams = make_cams(model)
    depth = 2.0 + torch.rand(3, cams.height, cams.width, generator=torch.Generator().manual_seed(0), dtype=DT)
    pts = cams.unproject(depth)  # [C, H, W, 3]
    uv, z = cams.project(pts.reshape(3, -1, 3))
    grid = cams.pixel_grid(DT).reshape(1, -1, 2).expand(3, -1, -1)
    torch.testing.assert_close(uv, grid, atol=1e-9, rtol=0)
    torch.testing.assert_close(z, depth.reshape(3, -1), atol=1e-9, rtol=0)


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_rays_agree_with_unproject(model):
    cams = make_cams(model)
    depth = torch.full((3, cams.height, cams.width), 3.5, dtype=DT)
    o, d = cams.rays()
    torch.testing.assert_close(o + 3.5 * d, cams.unproject(depth), atol=1e-9, rtol=0)
    # camera-space z of every direction is 1
    d_cam = torch.einsum("cij,chwj->chwi", cams.world_to_cam[:, :3, :3], d)
    torch.testing.assert_close(d_cam[..., 2], torch.ones_like(d_cam[..., 2]))
    if model == "orthographic":  # parallel rays along the viewing direction
        torch.testing.assert_close(d, cams.forward[:, None, None, :].expand_as(d))
    else:  # every ray starts at the camera centre
        torch.testing.assert_close(o, cams.centers[:, None, None, :].expand_as(o))


def test_pinhole_far_away_converges_to_orthographic():
    """Pinhole at distance d with focal f0 * d / d0 -> orthographic with f0 / d0 pixels per unit; the
    pixel error of points in a unit box falls like 1 / d."""
    f0, d0 = 30.0, 4.0
    pts = torch.rand(200, 3, generator=torch.Generator().manual_seed(1), dtype=DT) - 0.5
    ortho = make_cams("orthographic", dist=d0, f=f0 / d0)
    errors = []
    for d in (10.0, 100.0, 1000.0):
        pin = make_cams("pinhole", dist=d, f=f0 * d / d0)
        errors.append(float((pin.project(pts)[0] - ortho.project(pts)[0]).abs().max()))
    assert errors[0] > errors[1] > errors[2]
    assert errors[1] / errors[0] == pytest.approx(0.1, rel=0.1)  # ~1/d
    assert errors[2] / errors[1] == pytest.approx(0.1, rel=0.02)
    assert errors[2] < 1e-2  # pixels


def test_opengl_to_opencv():
    c2w_gl = torch.eye(4, dtype=DT)
    c2w_gl[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    c2w_cv = opengl_to_opencv(c2w_gl)
    # OpenGL looks down -z with y up; OpenCV looks down +z with y down: columns 1 and 2 flip sign
    torch.testing.assert_close(c2w_cv[:3, :3], torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=DT)))
    torch.testing.assert_close(c2w_cv[:3, 3], c2w_gl[:3, 3])
    cams = Cameras(torch.linalg.inv(c2w_cv), torch.tensor([[10.0, 0, 5], [0, 10, 5], [0, 0, 1]], dtype=DT), 10, 10)
    uv, z = cams.project(torch.tensor([[1.0, 3.0, -2.0]], dtype=DT))  # 5 units in front, 1 unit "up"
    assert float(z[0, 0]) == pytest.approx(5.0)
    assert float(uv[0, 0, 1]) == pytest.approx(5.0 - 10.0 * 1 / 5)  # up in the world = smaller row


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_scaled(model):
    cams = make_cams(model, w=20, h=14)
    half = cams.scaled(0.5)
    assert (half.width, half.height) == (10, 7)
    torch.testing.assert_close(half.K[:, :2], cams.K[:, :2] * 0.5)
    pts = torch.rand(50, 3, generator=torch.Generator().manual_seed(2), dtype=DT) - 0.5
    # continuous pixel coordinates scale exactly (pixel centres at +0.5 stay consistent with area resizing)
    torch.testing.assert_close(half.project(pts)[0], cams.project(pts)[0] * 0.5)
    torch.testing.assert_close(half.project(pts)[1], cams.project(pts)[1])


def test_batch_plumbing():
    cams = make_cams("pinhole")
    assert len(cams) == 3 and len(cams[1]) == 1 and len(cams[[0, 2]]) == 2
    both = Cameras.cat([cams[0], cams[2]])
    torch.testing.assert_close(both.world_to_cam, cams.world_to_cam[[0, 2]])
    with pytest.raises(ValueError, match="unknown camera model"):
        Cameras(cams.world_to_cam, cams.K, 20, 14, "fisheye")


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_project_gradients_through_the_in_place_sums(model):
    """``project`` adds the translation and the skew in place: gradients w.r.t. points, pose and intrinsics are still
    exact (float64 finite differences)."""
    eye = torch.tensor([[0.3, 0.2, -4.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[[200.0, 0.5, 72], [0, 190.0, 48], [0, 0, 1]]], dtype=torch.float64)
    pts = torch.randn(7, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    args = tuple(x.clone().requires_grad_() for x in (pts, w2c, K))
    assert torch.autograd.gradcheck(lambda p, w, k: Cameras(w, k, 144, 96, model).project(p), args)
