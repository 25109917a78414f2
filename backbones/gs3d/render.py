"""3D Gaussian splat rendering (Kerbl et al. 2023) on the tile rasteriser, pinhole and orthographic.

EWA splatting: ``Sigma2d = J W Sigma W^T J^T + 0.3 I`` with the Jacobian ``J`` of the camera
projection at the Gaussian's centre (pinhole ``[[fx/z, s/z, -(fx x + s y)/z^2], [0, fy/z, -fy y/z^2]]``,
orthographic ``[[fx, s, 0], [0, fy, 0]]``); conic = ``Sigma2d^-1``; radius ``ceil(3 sqrt(lambda_max))``;
``alpha = opacity exp(-d^T conic d / 2)`` (skipped where the exponent is positive, as the official code).
"""
from __future__ import annotations

import torch
from arcsem.backbones.gaussians.raster import (
    Segments,
    bin_tiles,
    composite_kept,
    effective_cutoff2,
    raster_impl,
    rasterize,
    screen_position_leaf,
    tile_rects,
    weights_record,
)
from arcsem.backbones.gaussians.raster_camera import pixel_projection
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.rotations import quat_to_rotmat
from arcsem.timing import region

__all__ = ["COV2D_BLUR", "footprint_3dgs", "project_gaussians", "render_3dgs"]

COV2D_BLUR = 0.3  # added to the diagonal of Sigma2d (official low-pass)


def project_gaussians(means: Tensor, quats: Tensor, scales: Tensor, cams: Cameras):
    """EWA projection.

    Returns: means2d ``[C, N, 2]``, depth ``[C, N]`` (camera z), cov2d ``[C, N, 2, 2]`` (with blur).
    """
    P = pixel_projection(cams).to(means.dtype)  # [C, 4, 4]: (x w, y w, w, z)
    hom = torch.einsum("cij,nj->cni", P[:, :, :3], means) + P[:, None, :, 3]
    w, depth = hom[..., 2], hom[..., 3]
    means2d = hom[..., :2] / w[..., None]
    # d(pixel)/d(world) = (P[:2] - pixel * P[2]) / w for both models (P[2] = 0 for orthographic)
    Jw = (P[:, None, :2, :3] - means2d[..., None] * P[:, None, 2:3, :3]) / w[..., None, None]
    R = quat_to_rotmat(quats)
    M = R * scales[:, None, :]  # R S
    JM = Jw @ M[None]
    cov2d = JM @ JM.transpose(-1, -2) + COV2D_BLUR * torch.eye(2, dtype=means.dtype, device=means.device)
    return means2d, depth, cov2d


def footprint_3dgs(means2d: Tensor, depth: Tensor, cov2d: Tensor, opacities: Tensor, cams: Cameras,
                   tile: int, near: float):
    """Radii ``[C, N]`` long, tile rects ``[C, N, 4]``, effective pixel boxes ``[C, N, 4]``, conic validity."""
    cov = cov2d.detach().double()
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * c - b * b
    mid = 0.5 * (a + c)
    lam = mid + (mid * mid - det).clamp_min(0.1).sqrt()
    ok = (det > 0) & (depth.detach() > near) & torch.isfinite(lam)
    radius = torch.where(ok, (3 * lam.clamp_min(0).sqrt()).ceil().clamp(max=1e7), torch.zeros_like(lam)).long()
    rects = tile_rects(means2d, radius, cams.width, cams.height, tile)
    cut2 = effective_cutoff2(opacities).expand_as(a)
    half = torch.stack([(cut2.clamp_min(0) * a).sqrt(), (cut2.clamp_min(0) * c).sqrt()], -1) * 1.001 + 0.01
    m2 = means2d.detach().double()
    lo = (m2 - half - 0.5).clamp(-1, max(cams.width, cams.height) + 1).ceil().long()
    hi = (m2 + half - 0.5).clamp(-2, max(cams.width, cams.height) + 1).floor().long()
    eff = torch.stack([lo[..., 0].clamp_min(0), hi[..., 0].clamp(max=cams.width - 1),
                       lo[..., 1].clamp_min(0), hi[..., 1].clamp(max=cams.height - 1)], -1)
    eff[..., 1] = torch.where(cut2 > 0, eff[..., 1], torch.full_like(eff[..., 1], -1))
    return radius, rects, eff, ok


def _shade_3dgs(table: Tensor):
    """Shader over ``table [10, M]`` (rows: means2d (2), conic (a, b, c), opacity, colour (3), depth):
    per-pixel ``[rgb(3), sum w z, alpha]``."""
    geo = table[:6].contiguous()

    def evaluate(G: tuple[Tensor, ...], xy: Tensor) -> Tensor:
        mx, my, ca, cb, cc, op = G[:6]
        x, y = xy.t().unbind(0)
        dx, dy = x - mx, y - my
        power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
        return torch.where(power > 0, torch.zeros_like(power), op * torch.exp(power))

    def alpha_fn(splat: Tensor, xy: Tensor) -> Tensor:
        return evaluate(torch.index_select(geo, 1, splat).unbind(0), xy)

    def shade(splat: Tensor, xy: Tensor, segs: Segments) -> Tensor:
        G = torch.index_select(table, 1, splat).unbind(0)
        w, _ = composite_kept(evaluate(G, xy), segs)
        return segs.sum(torch.stack([w * g for g in G[6:10]] + [w], 1))

    return alpha_fn, shade


def render_3dgs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                cams: Cameras, *, background: Tensor | None = None, tile: int = 16,
                chunk_tiles: int | None = None, near: float = 0.01, impl: str = "torch",
                colour_weights: bool = False) -> dict[str, Tensor]:
    """Render 3-D Gaussians.

    Args:
        means ``[N, 3]``, quats ``[N, 4]`` (w, x, y, z; unnormalised), scales ``[N, 3]``, opacities ``[N]``,
        colors ``[C, N, 3]`` or ``[N, 3]``, cams: ``C`` cameras; background ``[3]``; centres with depth
        ``<= near`` are culled. colour_weights: also return ``colour_weights``, the compositing weights of this
        geometry (:func:`arcsem.backbones.gaussians.fused.composite_weights`; the PyTorch path:
        :func:`arcsem.backbones.gaussians.raster.weights_record`).
    Returns:
        rgb ``[C, H, W, 3]``, alpha ``[C, H, W, 1]``, depth ``[C, H, W, 1]`` (``sum w z / alpha``),
        radii ``[C, N]`` long, visible ``[C, N]`` bool, means2d ``[C, N, 2]`` (a leaf whose ``.grad`` after
        backward is the gradient w.r.t. the screen positions, as in 2DGS).
    """
    impl = raster_impl(impl)
    if impl == "triton":
        raise ValueError("render_3dgs: the Triton rasteriser composites 2-D splats only (backbone=gs2d); use torch")
    C, N, H, W = len(cams), means.shape[0], cams.height, cams.width
    cams = cams.to(dtype=means.dtype)
    if impl == "cpp":
        return _render_3dgs_fused(means, quats, scales, opacities, colors, cams, background, tile, near, colour_weights)
    means2d, depth, cov2d = project_gaussians(means, quats, scales, cams)
    radius, rects, eff, ok = footprint_3dgs(means2d, depth, cov2d, opacities, cams, tile, near)
    b = bin_tiles(rects, depth, W, H, tile)
    det = cov2d[..., 0, 0] * cov2d[..., 1, 1] - cov2d[..., 0, 1] ** 2
    det = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([cov2d[..., 1, 1], -cov2d[..., 0, 1], cov2d[..., 0, 0]], -1) / det[..., None]
    colors = colors.expand(C, N, 3) if colors.ndim == 2 else colors
    feats = torch.cat([colors, depth[..., None]], -1).reshape(C * N, 4)
    leaf2d, shift = screen_position_leaf(means2d)
    table = torch.cat([(means2d + shift).reshape(C * N, 2), conics.reshape(C * N, 3), opacities.repeat(C)[:, None], feats], -1)
    table = table.t().contiguous()
    alpha_fn, shade = _shade_3dgs(table)
    out = rasterize(b, eff.reshape(C * N, 4), alpha_fn, shade, 5, means.dtype, chunk_tiles).reshape(C, H, W, 5)
    rgb, wz, alpha = out[..., :3], out[..., 3:4], out[..., 4:5]
    if background is not None:
        rgb = rgb + (1 - alpha) * background.to(rgb)
    visible = (radius > 0) & (rects[..., 1] > rects[..., 0]) & (rects[..., 3] > rects[..., 2])
    result = {
        "rgb": rgb, "alpha": alpha,
        "depth": torch.where(alpha > 0, wz / alpha.clamp_min(1e-30), torch.zeros_like(wz)),
        "radii": torch.where(visible, radius, torch.zeros_like(radius)), "visible": visible, "means2d": leaf2d,
    }
    if colour_weights:
        result["colour_weights"] = weights_record(b, eff.reshape(C * N, 4), alpha_fn, means.dtype, alpha, chunk_tiles)
    return result


def _render_3dgs_fused(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                       cams: Cameras, background: Tensor | None, tile: int, near: float,
                       colour_weights: bool = False) -> dict[str, Tensor]:
    """:func:`render_3dgs` on the fused C++ kernels (projection, footprint + binning, compositing)."""
    from arcsem.backbones.gaussians import fused

    C, N, H, W = len(cams), means.shape[0], cams.height, cams.width
    P = pixel_projection(cams).to(means.dtype)
    leaf = means.new_empty(C, N, 2).requires_grad_(torch.is_grad_enabled())
    with region("arcsem::render/project"):  # profiler regions: benchmarks/profile_step.py
        m2, depth, conics, cov = fused.project_3dgs(means, quats, scales, leaf, P, near)
        with torch.no_grad():
            leaf.copy_(m2.view(C, N, 2))
    opac = opacities.expand(C, N).reshape(C * N)
    bg = None if background is not None and background.requires_grad else background  # else composited here
    with region("arcsem::render/bin"):
        lists = fused.footprint_bin_3dgs(m2, depth, cov, opacities, C, near, W, H, tile)
    splats = (m2, conics, opac, colors.expand(C, N, 3).reshape(C * N, 3), depth)
    with region("arcsem::render/composite"):
        rgb, alpha, dmap = fused.composite3d(*splats, lists, C, H, W, tile, bg)
    if background is not None and bg is None:
        rgb = rgb + (1 - alpha) * background.to(rgb)
    out = {
        "rgb": rgb, "alpha": alpha, "depth": dmap,
        "radii": lists.radii.view(C, N), "visible": lists.visible.view(C, N), "means2d": leaf,
    }
    if colour_weights:
        out["colour_weights"] = fused.composite_weights("3d", *splats, lists=lists, C=C, H=H, W=W, tile=tile)
    return out
