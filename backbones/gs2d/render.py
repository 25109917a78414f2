"""2D Gaussian splat rendering (Huang et al. 2024) on the tile rasteriser, pinhole and orthographic.

Ray-splat intersection via the homography ``T = P @ S`` (docs/method.md): ``S`` maps splat coordinates
``(u, v, 1)`` to homogeneous world points ``p + u t_u + v t_v`` and ``P`` (:func:`pixel_projection`)
maps world points to ``(x w, y w, w, z)``; the rows of ``T`` are ``Tu, Tv, Tw`` and the depth row
``Tz``. For pixel ``(x, y)``: ``k = x Tw - Tu``, ``l = y Tw - Tv``, ``(u, v, 1) ~ k x l``. For an
orthographic camera ``Tw = (0, 0, 1)``, so the same code applies.
"""
from __future__ import annotations

import torch
from arcsem.backbones.gaussians.config import LOWPASS_SIGMA
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
from arcsem.backbones.gaussians.raster_camera import camera_facing_normals, pixel_projection
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.rotations import quat_to_rotmat
from arcsem.timing import region

__all__ = ["DIST_FAR", "DIST_NEAR", "LOWPASS_SIGMA", "distortion_depth", "footprint_2dgs", "render_2dgs",
           "splat_homographies"]

DIST_NEAR, DIST_FAR = 0.2, 100.0  # normalised depth m = far/(far-near) (1 - near/z) (official 2DGS)


def distortion_depth(mode: str = "ndc", length: float = 1.0) -> tuple[float, float, float]:
    """Coefficients ``(c0, c1, c2)`` of the distortion term's normalised depth ``m = c0 + c1 z + c2 / z``.

    ``ndc``: the official 2DGS mapping ``far/(far-near) (1 - near/z)`` (near 0.2, far 100). Its slope
    ``0.2/z^2`` vanishes for SEM's near-orthographic cameras (z ~ 70 scene units: 4e-5 per unit), so
    the loss cannot act; ``linear``: ``m = z / length`` (e.g. the scene extent), the same at any
    camera distance and for orthographic cameras.
    """
    if mode == "ndc":
        a = DIST_FAR / (DIST_FAR - DIST_NEAR)
        return (a, 0.0, -a * DIST_NEAR)
    if mode == "linear":
        if not length > 0:
            raise ValueError(f"distortion_depth: length must be > 0, got {length}")
        return (0.0, 1.0 / length, 0.0)
    raise ValueError(f"distortion_depth: mode must be 'ndc' or 'linear', got '{mode}'")
# Screen-space low-pass filter (2DGS): a splat is drawn at least as the 2-D Gaussian of this sigma (pixels)
# around its projected centre, rho = min(rho3d, |pixel - centre|^2 / sigma^2). Official: rho2d = 2 |d|^2.
# LOWPASS_SIGMA: the official 1/sqrt(2) (arcsem.backbones.gaussians.config), the gs2d Config default


def splat_homographies(means: Tensor, quats: Tensor, scales: Tensor, cams: Cameras) -> tuple[Tensor, Tensor]:
    """Per camera and splat homography ``[C, N, 4, 3]`` (rows Tu, Tv, Tw, Tz) and rotations ``[N, 3, 3]``."""
    R = quat_to_rotmat(quats)
    N = means.shape[0]
    S = means.new_zeros(N, 4, 3)
    S[:, :3, 0] = R[:, :, 0] * scales[:, :1]
    S[:, :3, 1] = R[:, :, 1] * scales[:, 1:2]
    S[:, :3, 2] = means
    S[:, 3, 2] = 1.0
    P = pixel_projection(cams).to(means.dtype)
    return torch.einsum("cij,njk->cnik", P, S), R


def _conic_box(T: Tensor, cut2: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Bounding box of the image of the disk ``u^2 + v^2 <= cut2`` (dual conic ``T diag(1,1,-1/cut2) T^T``).

    Args: T ``[..., 3, 3]`` rows Tu, Tv, Tw (float64, detached); cut2 ``[...]``.
    Returns: centre ``[..., 2]``, half extent ``[..., 2]``, valid ``[...]`` (the disk lies in front of
    the camera, so the image is an ellipse).
    """
    f = torch.stack([torch.ones_like(cut2), torch.ones_like(cut2), -1.0 / cut2], -1)
    D = torch.einsum("...ik,...k,...jk->...ij", T, f, T)
    d22 = D[..., 2, 2]
    valid = d22 < 0  # signature (+,+,-): the line at infinity misses the conic -> ellipse
    d22s = torch.where(valid, d22, torch.ones_like(d22))
    c = torch.stack([D[..., 0, 2], D[..., 1, 2]], -1) / d22s[..., None]
    e2 = c * c - torch.stack([D[..., 0, 0], D[..., 1, 1]], -1) / d22s[..., None]
    return c, e2.clamp_min(1e-4).sqrt(), valid


def footprint_2dgs(H: Tensor, opacities: Tensor, cams: Cameras, tile: int, near: float,
                   lowpass_sigma: float = LOWPASS_SIGMA):
    """Screen footprint of 2-D splats (no gradient).

    Args: H ``[C, N, 4, 3]`` homographies; opacities ``[N]``; lowpass_sigma: the low-pass filter's sigma (px).
    Returns: radii ``[C, N]`` long (3 sigma, official: ``ceil(max(extent, 3 lowpass_sigma))``), rects
    ``[C, N, 4]`` tile rectangles, effective pixel boxes ``[C, N, 4]`` long, centre depth ``[C, N]``.
    """
    T = H.detach().double()
    depth = T[..., 3, 2]
    centre2d = T[..., :2, 2] / T[..., 2, 2:3]
    c3, e3, ok3 = _conic_box(T[..., :3, :], torch.full_like(depth, 9.0))
    ok = ok3 & (depth > near) & torch.isfinite(e3).all(-1)
    radius = torch.maximum(e3.amax(-1), torch.full_like(depth, 3.0 * lowpass_sigma)).ceil()
    radius = torch.where(ok, radius.clamp(max=1e7), torch.zeros_like(radius)).long()
    rects = tile_rects(c3, radius, cams.width, cams.height, tile)
    # effective box: union of the low-pass circle and the ellipse with the opacity cutoff
    cut2 = effective_cutoff2(opacities).expand_as(depth)
    ce, ee, oke = _conic_box(T[..., :3, :], cut2.clamp_min(1e-6))
    r2d = cut2.clamp_min(0).sqrt()[..., None] * lowpass_sigma
    inf = torch.full_like(ce, float("inf"))
    lo = torch.minimum(torch.where(oke[..., None], ce - ee, -inf), centre2d - r2d) - 0.01
    hi = torch.maximum(torch.where(oke[..., None], ce + ee, inf), centre2d + r2d) + 0.01
    eff = _pixel_box(lo, hi, cams.width, cams.height, cut2 > 0)
    return radius, rects, eff, depth


def _pixel_box(lo: Tensor, hi: Tensor, W: int, H: int, ok: Tensor) -> Tensor:
    """``[..., 2]`` float bounds -> ``[..., 4]`` long inclusive pixel-index box (pixel centres inside)."""
    lo = (lo - 0.5).clamp(-1, max(W, H) + 1).ceil().long()
    hi = (hi - 0.5).clamp(-2, max(W, H) + 1).floor().long()
    box = torch.stack([lo[..., 0].clamp_min(0), hi[..., 0].clamp(max=W - 1),
                       lo[..., 1].clamp_min(0), hi[..., 1].clamp(max=H - 1)], -1)
    box[..., 1] = torch.where(ok, box[..., 1], torch.full_like(box[..., 1], -1))
    return box


def _splat_table(Hm: Tensor, centre2d: Tensor, opac: Tensor, feats: Tensor) -> Tensor:
    """``[21, M]`` per (camera, splat), one row per quantity: adjugate columns a, b, c of ``[Tu; Tv; Tw]``
    (``(u, v, 1) ~ x a + y b + c``), centre ``(2)``, opacity, depth row ``Tz (3)``, colour, normal ``(6)``.
    Rows are gathered per pair-pixel and unbound at once (cheap backward: one stack, no slice copies). Transposed,
    the Triton kernels' table (``triton2d.TABLE``)."""
    Tu, Tv, Tw, Tz = Hm.unbind(1)
    adj = [torch.cross(Tv, Tw, dim=-1), torch.cross(Tw, Tu, dim=-1), torch.cross(Tu, Tv, dim=-1)]
    return torch.cat([*adj, centre2d, opac[:, None], Tz, feats], -1).t().contiguous()


def _shade_2dgs(table: Tensor, mcoef: tuple[float, float, float], lowpass_sigma: float = LOWPASS_SIGMA):
    """Shader for :func:`rasterize`: per-pixel ``[rgb(3), normal(3), alpha, sum w z, distortion, median]``."""
    inv2 = 1.0 / lowpass_sigma**2
    geo = table[:12].contiguous()

    def evaluate(G: tuple[Tensor, ...], xy: Tensor):
        a0, a1, a2, b0, b1, b2, c0, c1, c2, cx, cy, op = G[:12]
        x, y = xy.t().unbind(0)
        q0 = torch.addcmul(torch.addcmul(c0, x, a0), y, b0)
        q1 = torch.addcmul(torch.addcmul(c1, x, a1), y, b1)
        q2 = torch.addcmul(torch.addcmul(c2, x, a2), y, b2)
        qz = torch.where(q2.abs() < 1e-12, torch.full_like(q2, 1e-12), q2)
        rho3d = (q0 * q0 + q1 * q1) / (qz * qz)
        dx, dy = x - cx, y - cy
        rho2d = inv2 * (dx * dx + dy * dy)
        use3d = rho3d <= rho2d
        alpha = op * torch.exp(-0.5 * torch.where(use3d, rho3d, rho2d))
        return alpha, use3d, q0, q1, qz

    def alpha_fn(splat: Tensor, xy: Tensor) -> Tensor:
        return evaluate(torch.index_select(geo, 1, splat).unbind(0), xy)[0]

    def shade(splat: Tensor, xy: Tensor, segs: Segments) -> Tensor:
        G = torch.index_select(table, 1, splat).unbind(0)
        alpha, use3d, q0, q1, qz = evaluate(G, xy)
        tz0, tz1, tz2 = G[12:15]
        c0, c1, c2 = mcoef
        z = torch.where(use3d, (q0 * tz0 + q1 * tz1) / qz + tz2, tz2)
        w, T = composite_kept(alpha, segs)
        m = c0 + c1 * z + c2 / z
        # the distortion sum_ij w_i w_j (m_i - m_j)^2 is invariant to shifting m per pixel: shifting by
        # the pixel's first m avoids the cancellation of m^2 A + M2 - 2 m M1 (float32 error 1e-3 -> 1e-6)
        m = m - torch.index_select(m.detach(), 0, segs.start)
        wm = w * m
        dist = w * (m * m * (1 - T) + segs.excl_cumsum(wm * m) - 2 * m * segs.excl_cumsum(wm))
        cols = [w * g for g in G[15:21]] + [w, w * z, dist]  # rgb, normal, alpha, w z, distortion
        sums = segs.sum(torch.stack(cols, 1))
        last = segs.last(T.detach() > 0.5)
        median = torch.where(last >= 0, torch.index_select(z, 0, last.clamp_min(0)), torch.zeros_like(sums[:, 0]))
        return torch.cat([sums, median[:, None]], -1)

    return alpha_fn, shade


def render_2dgs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                cams: Cameras, *, background: Tensor | None = None, tile: int = 16,
                chunk_tiles: int | None = None, near: float = 0.01, impl: str = "torch",
                dist_depth: tuple[float, float, float] | None = None,
                lowpass_sigma: float = LOWPASS_SIGMA, colour_weights: bool = False) -> dict[str, Tensor]:
    """Render 2-D Gaussian splats.

    Args:
        means ``[N, 3]``, quats ``[N, 4]`` (w, x, y, z; unnormalised), scales ``[N, 2]``, opacities ``[N]``
        in (0, 1), colors ``[C, N, 3]`` or ``[N, 3]`` (decoded), cams: ``C`` cameras (pinhole or
        orthographic); background ``[3]`` composited as ``rgb + (1 - alpha) bg``; splats whose centre
        depth is ``<= near`` are culled.
        impl: ``torch`` (this module, the reference), ``cpp`` (fused kernels), ``auto``, or ``triton`` (projection,
            footprints and compositing as Triton kernels, this module's tile binning: :mod:`..gaussians.triton2d`).
        dist_depth: ``(c0, c1, c2)`` of the distortion's normalised depth (:func:`distortion_depth`;
        default the official NDC mapping).
        lowpass_sigma: sigma (pixels) of the screen-space low-pass filter (official ``1/sqrt(2)``). It
        widens every silhouette by about one sigma, which a fit to sharp silhouettes pays for by
        shrinking the surface (see the gs2d backbone's ``lowpass_sigma``).
        colour_weights: also return ``colour_weights``, the compositing weights of this geometry
        (:func:`arcsem.backbones.gaussians.fused.composite_weights`; the PyTorch path:
        :func:`arcsem.backbones.gaussians.raster.weights_record`).
    Returns:
        rgb ``[C, H, W, 3]``, alpha, depth (``sum w z / alpha``), median_depth, distortion ``[C, H, W, 1]``,
        normal ``[C, H, W, 3]`` (world, ``sum w n``), radii ``[C, N]`` long, visible ``[C, N]`` bool,
        means2d ``[C, N, 2]``: projected centres, a leaf whose ``.grad`` after backward is the gradient
        w.r.t. the splats' screen positions (for densification).
    """
    impl = raster_impl(impl)
    C, N, Hh, W = len(cams), means.shape[0], cams.height, cams.width
    cams = cams.to(dtype=means.dtype)
    mcoef = tuple(float(c) for c in (dist_depth or distortion_depth("ndc")))
    if impl == "cpp":
        return _render_2dgs_fused(means, quats, scales, opacities, colors, cams, background, tile, near, mcoef,
                                  lowpass_sigma, colour_weights)
    if impl == "triton":
        return _render_2dgs_triton(means, quats, scales, opacities, colors, cams, background, tile, near, mcoef,
                                   lowpass_sigma, chunk_tiles, colour_weights)
    Hm, R = splat_homographies(means, quats, scales, cams)
    radius, rects, eff, depth = footprint_2dgs(Hm, opacities, cams, tile, near, lowpass_sigma)
    b = bin_tiles(rects, depth, W, Hh, tile)
    normals = camera_facing_normals(R[:, :, 2], means, cams)
    colors = colors.expand(C, N, 3) if colors.ndim == 2 else colors
    feats = torch.cat([colors, normals], -1).reshape(C * N, 6)
    means2d, shift = screen_position_leaf(Hm[..., :2, 2] / Hm[..., 2, 2:3])
    # translating a splat's image by (dx, dy) pixels: Tu += dx Tw, Tv += dy Tw (dx, dy = 0 in value)
    Hm = torch.cat([Hm[..., :2, :] + shift[..., None] * Hm[..., 2:3, :], Hm[..., 2:, :]], -2)
    centre2d = (Hm[..., :2, 2] / Hm[..., 2, 2:3]).reshape(C * N, 2)
    alpha_fn, shade = _shade_2dgs(_splat_table(Hm.reshape(C * N, 4, 3), centre2d, opacities.repeat(C), feats), mcoef,
                                  lowpass_sigma)
    out = rasterize(b, eff.reshape(C * N, 4), alpha_fn, shade, 10, means.dtype, chunk_tiles).reshape(C, Hh, W, 10)
    result = {**_outputs(out, background, radius, rects), "means2d": means2d}
    if colour_weights:
        result["colour_weights"] = weights_record(b, eff.reshape(C * N, 4), alpha_fn, means.dtype, result["alpha"],
                                                  chunk_tiles)
    return result


def _render_2dgs_fused(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                       cams: Cameras, background: Tensor | None, tile: int, near: float,
                       mcoef: tuple[float, float, float], lowpass_sigma: float,
                       colour_weights: bool = False) -> dict[str, Tensor]:
    """:func:`render_2dgs` on the fused C++ kernels: projection, footprint + binning and compositing are one
    call each (few PyTorch ops: on a shared machine every multi-threaded op can cost a scheduler slice)."""
    from arcsem.backbones.gaussians import fused

    C, N, Hh, W = len(cams), means.shape[0], cams.height, cams.width
    P = pixel_projection(cams).to(means.dtype)
    view = (cams.forward if cams.is_ortho else cams.centers).to(means.dtype)
    # the screen-position leaf (means2d.grad): only where the geometry trains (a frozen one skips its gradients)
    leaf = means.new_empty(C, N, 2).requires_grad_(torch.is_grad_enabled() and means.requires_grad)
    with region("arcsem::render/project"):  # profiler regions: benchmarks/profile_step.py
        H9, Dz, centre2d, normals = fused.project_2dgs(means, quats, scales, leaf, P, view, cams.is_ortho)
        with torch.no_grad():
            leaf.copy_(centre2d.view(C, N, 2))
    opac = opacities.expand(C, N).reshape(C * N)
    bg = None if background is not None and background.requires_grad else background  # else composited here
    with region("arcsem::render/bin"):
        lists = fused.footprint_bin_2dgs(H9, Dz, opacities, C, near, W, Hh, tile, lowpass_sigma)
    surfels = (H9, Dz, centre2d, opac, colors.expand(C, N, 3).reshape(C * N, 3), normals,
               means.new_tensor(mcoef).expand(C, 3))
    with region("arcsem::render/composite"):
        rgb, normal, alpha, depth, med, dist = fused.composite2d(*surfels, lists, float("-inf"), C, Hh, W, tile, bg,
                                                                 lowpass_sigma)
    if background is not None and bg is None:
        rgb = rgb + (1 - alpha) * background.to(rgb)
    out = {
        "rgb": rgb, "alpha": alpha, "depth": depth, "median_depth": med, "normal": normal, "distortion": dist,
        "radii": lists.radii.view(C, N), "visible": lists.visible.view(C, N), "means2d": leaf,
    }
    if colour_weights:
        out["colour_weights"] = fused.composite_weights("2d", *surfels, lists=lists, C=C, H=Hh, W=W, tile=tile,
                                                        near=float("-inf"), lowpass_sigma=lowpass_sigma)
    return out


def _render_2dgs_triton(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                        cams: Cameras, background: Tensor | None, tile: int, near: float,
                        mcoef: tuple[float, float, float], lowpass_sigma: float, chunk_tiles: int | None,
                        colour_weights: bool = False) -> dict[str, Tensor]:
    """:func:`render_2dgs` on Triton kernels (CUDA; :mod:`..gaussians.triton2d`): the projection to the splat table
    (forward and backward), the footprints and the compositing (forward and backward) are a launch each, the tile
    binning's expansion to pairs too (its depth ranks, sort and offsets PyTorch's: ``gaussians/_triton2d_bin.py``)."""
    from arcsem.backbones.gaussians._triton2d_footprint import footprint_bin_2dgs_triton
    from arcsem.backbones.gaussians._triton2d_project import project_2dgs_triton
    from arcsem.backbones.gaussians.triton2d import composite2d_triton

    C, N, Hh, W = len(cams), means.shape[0], cams.height, cams.width
    P = pixel_projection(cams)
    view = cams.forward if cams.is_ortho else cams.centers
    leaf = means.new_empty(C, N, 2).requires_grad_(torch.is_grad_enabled() and means.requires_grad)
    with region("arcsem::render/project"):  # profiler regions: benchmarks/profile_step.py
        table, hm = project_2dgs_triton(means, quats, scales, opacities, colors.expand(C, N, 3), leaf, P, view,
                                        cams.is_ortho)
        with torch.no_grad():
            leaf.copy_(table[:, 9:11].view(C, N, 2))
    with region("arcsem::render/bin"):
        radius, rects, eff, b = footprint_bin_2dgs_triton(hm.view(C, N, 4, 3), opacities, W, Hh, tile, near,
                                                          lowpass_sigma)
    bg = None if background is not None and background.requires_grad else background  # else composited here
    geometry = any(t.requires_grad for t in (means, quats, scales, opacities))  # else colours alone (stage 2)
    with region("arcsem::render/composite"):
        rgb, normal, alpha, depth, med, dist = composite2d_triton(table, eff.reshape(C * N, 4), b.offsets, b.splat,
                                                                  mcoef, C, Hh, W, tile, bg,
                                                                  lowpass_sigma=lowpass_sigma, geometry=geometry)
    if background is not None and bg is None:
        rgb = rgb + (1 - alpha) * background.to(rgb)
    out = {"rgb": rgb, "alpha": alpha, "depth": depth, "median_depth": med, "normal": normal, "distortion": dist,
           **_visibility(radius, rects), "means2d": leaf}
    if colour_weights:  # stage 2's record: the PyTorch path's, on the same table and tile lists
        alpha_fn, _ = _shade_2dgs(table.detach().t().contiguous(), mcoef, lowpass_sigma)
        out["colour_weights"] = weights_record(b, eff.reshape(C * N, 4), alpha_fn, means.dtype, alpha, chunk_tiles)
    return out


def _visibility(radius: Tensor, rects: Tensor) -> dict[str, Tensor]:
    """``radii`` and ``visible [C, N]``: drawn with a non-empty tile rectangle."""
    visible = (radius > 0) & (rects[..., 1] > rects[..., 0]) & (rects[..., 3] > rects[..., 2])
    return {"radii": torch.where(visible, radius, torch.zeros_like(radius)), "visible": visible}


def _outputs(out: Tensor, background: Tensor | None, radius: Tensor, rects: Tensor) -> dict[str, Tensor]:
    rgb, alpha, wz = out[..., :3], out[..., 6:7], out[..., 7:8]
    depth = torch.where(alpha > 0, wz / alpha.clamp_min(1e-30), torch.zeros_like(wz))
    if background is not None:
        rgb = rgb + (1 - alpha) * background.to(rgb)
    return {
        "rgb": rgb, "alpha": alpha, "depth": depth, "median_depth": out[..., 9:10],
        "normal": out[..., 3:6], "distortion": out[..., 8:9], **_visibility(radius, rects),
    }
