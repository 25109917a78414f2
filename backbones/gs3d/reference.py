"""Dense reference renderer for 3DGS: every Gaussian against every pixel, one Gaussian at a time.

Plain code for tests and benchmarks. Independent of the renderer's maths: the Jacobian of the
projection is taken by autograd through ``Cameras.project`` (kept differentiable with
``create_graph``), the rotation comes from quaternion products, and the conic from
``torch.linalg.inv``. Only the discrete footprint (tile rectangles, culling) comes from the renderer.
"""
from __future__ import annotations

import torch
from arcsem.backbones.gaussians.dense import rotate_by_quat, tile_mask
from arcsem.backbones.gaussians.raster import MAX_ALPHA, MIN_ALPHA, MIN_T
from arcsem.backbones.gs3d.render import COV2D_BLUR, footprint_3dgs, project_gaussians
from torch import Tensor

from arcsem.cameras import Cameras

__all__ = ["render_3dgs_dense"]


def _cov2d(means: Tensor, quats: Tensor, scales: Tensor, cam: Cameras) -> Tensor:
    """``[N, 2, 2]`` projected covariance ``J Sigma J^T + 0.3 I`` with ``J = d pixel / d world`` by autograd."""
    eye = torch.eye(3, dtype=means.dtype)
    Rcols = torch.stack([rotate_by_quat(quats, eye[i]) for i in range(3)], -1)  # [N, 3, 3]
    Sigma = Rcols @ torch.diag_embed(scales ** 2) @ Rcols.transpose(1, 2)
    rows = []
    with torch.enable_grad():
        rows = _jacobian_rows(means, cam)
    J = torch.stack(rows, 1)  # [N, 2, 3]
    return J @ Sigma @ J.transpose(1, 2) + COV2D_BLUR * torch.eye(2, dtype=means.dtype)


def _jacobian_rows(means: Tensor, cam: Cameras) -> list[Tensor]:
    rows = []
    for k in range(2):  # d pixel_k / d means, for all splats at once (each pixel depends on its own splat)
        px = cam.project(means)[0][0, :, k].sum()
        rows.append(torch.autograd.grad(px, means, create_graph=True)[0])
    return rows


def _one_camera(means, quats, scales, opac, colors, cam: Cameras, rects, radius, tile):
    if not means.requires_grad:
        means = means.detach().requires_grad_(True)
    with torch.enable_grad():
        return _one_camera_grad(means, quats, scales, opac, colors, cam, rects, radius, tile)


def _one_camera_grad(means, quats, scales, opac, colors, cam: Cameras, rects, radius, tile):
    c2d, cz = cam.project(means)
    c2d, cz = c2d[0], cz[0]
    conic = torch.linalg.inv(_cov2d(means, quats, scales, cam))
    pix = cam.pixel_grid(means.dtype).reshape(-1, 1, 2)
    d = pix - c2d  # [P, N, 2]
    power = -0.5 * torch.einsum("pni,nij,pnj->pn", d, conic, d)
    alpha = torch.where(power > 0, torch.zeros_like(power), opac * torch.exp(power)).clamp(max=MAX_ALPHA)
    mask = tile_mask(rects, cam.width, cam.height, tile) & (radius > 0)
    P = pix.shape[0]
    T, done = alpha.new_ones(P), torch.zeros(P, dtype=torch.bool)
    rgb, acc, wz = alpha.new_zeros(P, 3), alpha.new_zeros(P), alpha.new_zeros(P)
    for j in torch.argsort(cz, stable=True).tolist():
        a = alpha[:, j]
        active = mask[:, j] & ~done & (a >= MIN_ALPHA)
        test_T = T * (1 - a)
        stop = active & (test_T < MIN_T)
        done, active = done | stop, active & ~stop
        w = torch.where(active, a * T, torch.zeros_like(a))
        rgb, acc, wz = rgb + w[:, None] * colors[j], acc + w, wz + w * cz[j]
        T = torch.where(active, test_T, T)
    return rgb, acc, torch.where(acc > 0, wz / acc.clamp_min(1e-30), torch.zeros_like(wz))


def render_3dgs_dense(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                      cams: Cameras, *, background: Tensor | None = None, tile: int = 16,
                      near: float = 0.01) -> dict[str, Tensor]:
    """Same inputs and image outputs as :func:`arcsem.backbones.gs3d.render.render_3dgs`."""
    cams = cams.to(dtype=means.dtype)
    C, N, H, W = len(cams), means.shape[0], cams.height, cams.width
    with torch.no_grad():
        m2, z, cov = project_gaussians(means, quats, scales, cams)
        radius, rects, _, _ = footprint_3dgs(m2, z, cov, opacities, cams, tile, near)
    colors = colors.expand(C, N, 3) if colors.ndim == 2 else colors
    outs = [_one_camera(means, quats, scales, opacities, colors[c], cams[c], rects[c], radius[c], tile)
            for c in range(C)]
    rgb, acc, depth = (torch.stack([o[i] for o in outs]) for i in range(3))
    if background is not None:
        rgb = rgb + (1 - acc[..., None]) * background.to(rgb)
    return {"rgb": rgb.reshape(C, H, W, 3), "alpha": acc.reshape(C, H, W, 1), "depth": depth.reshape(C, H, W, 1)}
