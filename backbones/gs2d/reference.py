"""Dense reference renderer for 2DGS: every splat against every pixel, one splat at a time.

Plain code written for clarity, not speed; tests and benchmarks compare :func:`render_2dgs` with it.
It computes the intersection independently of the homography: a world-space ray (from
``Cameras.rays``) meets the splat plane ``p + u t_u + v t_v`` (a 3x3 linear solve), the hit depth
is the ray parameter (rays have unit camera z and start at camera z = 0 for both models). Only the
discrete footprint (which tiles a splat touches, the culling) is taken from the renderer, since it
is a definition rather than maths to check.
"""
from __future__ import annotations

import torch
from arcsem.backbones.gaussians.dense import rotate_by_quat as _rotate_by_quat
from arcsem.backbones.gaussians.dense import tile_mask
from arcsem.backbones.gaussians.raster import MAX_ALPHA, MIN_ALPHA, MIN_T
from arcsem.backbones.gs2d.render import LOWPASS_SIGMA, distortion_depth, footprint_2dgs, splat_homographies
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.lazy import moved_getattr

__all__ = ["render_2dgs_dense"]

# rotate_by_quat moved to arcsem.backbones.gaussians.dense (gs3d's reference uses it too); imported above as
# _rotate_by_quat so that the old public path goes through moved_getattr and warns
__getattr__ = moved_getattr(__name__, {"rotate_by_quat": "arcsem.backbones.gaussians.dense"})


def _one_camera(means, quats, scales, opac, colors, cam: Cameras, rects, radius, tile, dist_depth=None,
                lowpass_sigma=LOWPASS_SIGMA):
    N = means.shape[0]
    eye = torch.eye(3, dtype=means.dtype)
    tu = _rotate_by_quat(quats, eye[0]) * scales[:, :1]
    tv = _rotate_by_quat(quats, eye[1]) * scales[:, 1:]
    n = _rotate_by_quat(quats, eye[2])
    toward = cam.forward[0] if cam.is_ortho else means - cam.centers[0]
    n = torch.where((n * toward).sum(-1, keepdim=True) > 0, -n, n)
    o, d = cam.rays()
    o, d = o.reshape(-1, 1, 3), d.reshape(-1, 1, 3)
    P = o.shape[0]
    A = torch.stack([tu.expand(P, N, 3), tv.expand(P, N, 3), -d.expand(P, N, 3)], -1)
    uvs = torch.linalg.solve(A, (o - means)[..., None])[..., 0]  # [P, N, 3]
    rho3d = uvs[..., 0] ** 2 + uvs[..., 1] ** 2
    c2d, cz = cam.project(means)
    pix = cam.pixel_grid(means.dtype).reshape(-1, 1, 2)
    rho2d = ((pix - c2d) ** 2).sum(-1) / lowpass_sigma**2
    alpha = (opac * torch.exp(-0.5 * torch.minimum(rho3d, rho2d))).clamp(max=MAX_ALPHA)
    z = torch.where(rho3d <= rho2d, uvs[..., 2], cz.expand(P, N))
    c0, c1, c2 = dist_depth or distortion_depth("ndc")
    m = c0 + c1 * z + c2 / z
    mask = tile_mask(rects, cam.width, cam.height, tile) & (radius > 0)
    return _composite_loop(alpha, mask, z, m, colors, n, torch.argsort(cz[0], stable=True))


def _composite_loop(alpha, mask, z, m, colors, n, order):
    """Front-to-back loop over splats in ``order`` with the official skip / clamp / stop rules."""
    P = alpha.shape[0]
    T = alpha.new_ones(P)
    done = torch.zeros(P, dtype=torch.bool)
    rgb, nrm = alpha.new_zeros(P, 3), alpha.new_zeros(P, 3)
    acc, wz, dist, M1, M2, med = (alpha.new_zeros(P) for _ in range(6))
    for j in order.tolist():
        a = alpha[:, j]
        active = mask[:, j] & ~done & (a >= MIN_ALPHA)
        test_T = T * (1 - a)
        stop = active & (test_T < MIN_T)
        done = done | stop
        active = active & ~stop
        w = torch.where(active, a * T, torch.zeros_like(a))
        mj = m[:, j]
        dist = dist + w * (mj * mj * (1 - T) + M2 - 2 * mj * M1)
        M1, M2 = M1 + w * mj, M2 + w * mj * mj
        med = torch.where(active & (T > 0.5), z[:, j], med)
        rgb = rgb + w[:, None] * colors[j]
        nrm = nrm + w[:, None] * n[j]
        acc, wz = acc + w, wz + w * z[:, j]
        T = torch.where(active, test_T, T)
    depth = torch.where(acc > 0, wz / acc.clamp_min(1e-30), torch.zeros_like(wz))
    return rgb, acc, depth, med, nrm, dist


def render_2dgs_dense(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                      cams: Cameras, *, background: Tensor | None = None, tile: int = 16,
                      near: float = 0.01, dist_depth: tuple[float, float, float] | None = None,
                      lowpass_sigma: float = LOWPASS_SIGMA) -> dict[str, Tensor]:
    """Same inputs and image outputs as :func:`arcsem.backbones.gs2d.render.render_2dgs`."""
    cams = cams.to(dtype=means.dtype)
    C, N, H, W = len(cams), means.shape[0], cams.height, cams.width
    with torch.no_grad():
        Hm, _ = splat_homographies(means, quats, scales, cams)
        radius, rects, _, _ = footprint_2dgs(Hm, opacities, cams, tile, near, lowpass_sigma)
    colors = colors.expand(C, N, 3) if colors.ndim == 2 else colors
    outs = [_one_camera(means, quats, scales, opacities, colors[c], cams[c], rects[c], radius[c], tile, dist_depth,
                       lowpass_sigma)
            for c in range(C)]
    rgb, acc, depth, med, nrm, dist = (torch.stack([o[i] for o in outs]) for i in range(6))
    if background is not None:
        rgb = rgb + (1 - acc[..., None]) * background.to(rgb)
    img = lambda x, k: x.reshape(C, H, W, k)
    return {"rgb": img(rgb, 3), "alpha": img(acc, 1), "depth": img(depth, 1), "median_depth": img(med, 1),
            "normal": img(nrm, 3), "distortion": img(dist, 1)}
