"""Fused C++ CPU compositing kernels (forward + backward), built as a PyTorch JIT extension.

The kernels in ``cpp/`` cover the whole ``rasterizer: cpp`` pipeline in a few calls (on a shared,
oversubscribed 2-core machine every multi-threaded PyTorch op can cost a scheduler slice, so op count
matters as much as arithmetic): the differentiable projection (``project.cpp``: 2DGS homographies and
normals, 3DGS EWA conics, with backward kernels), footprints + tile binning + depth sort (``binning.cpp``,
no gradient) and the front-to-back compositing (``composite2d.cpp``, ``composite3d.cpp``). The PyTorch
path is the reference: tests/test_fused.py checks values and gradients of both paths against each other.

``load_extension()`` compiles once (about a minute with gcc; cached under
``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``) and returns None with one warning when
the toolchain is missing, so ``rasterizer: auto`` falls back to PyTorch.
"""
from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext

__all__ = [
    "EXTENSION",
    "composite2d",
    "composite3d",
    "footprint_bin_2dgs",
    "footprint_bin_3dgs",
    "load_extension",
    "project_2dgs",
    "project_3dgs",
    "resolve_impl",
]

CPP_DIR = Path(__file__).parent / "cpp"
EXTENSION = cext.Extension(
    prefix="arcsem_fused_raster",
    sources=tuple(CPP_DIR / n for n in ("composite3d.cpp", "composite2d.cpp", "binning.cpp", "project.cpp", "module.cpp")),
    what="fused C++ Gaussian rasteriser",
)


def load_extension(verbose: bool = False):
    """The compiled module, or None (with one warning) when it cannot be built (:func:`arcsem.cext.load`)."""
    return cext.load(EXTENSION, verbose)


load_extension.cache_clear = cext.load.cache_clear  # tests simulate a missing toolchain


def resolve_impl(impl: str, device: str = "cpu") -> str:
    """``rasterizer`` value ``auto|torch|cpp`` -> the path taken (:func:`arcsem.cext.resolve_impl`)."""
    return cext.resolve_impl(impl, EXTENSION, device)


def _grad(g: Tensor | None) -> Tensor:
    """An output gradient for the kernels: None (output unused) -> an empty tensor, read as zero."""
    return torch.empty(0) if g is None else g.contiguous()


class _Composite3D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depth, offsets, ids, box, bg, C, H, W, tile):
        ext = load_extension()
        rgb, alpha, dep, f, tf, last, wz = ext.forward3d(means2d, conics, opacities, colors, depth, offsets, ids, box,
                                                          bg, C, H, W, tile)
        ctx.save_for_backward(means2d, conics, opacities, f, offsets, ids, box, bg, tf, last, alpha, wz)
        ctx.dims = (C, H, W, tile)
        ctx.set_materialize_grads(False)
        return rgb, alpha, dep

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_depth):
        means2d, conics, opacities, f, offsets, ids, box, bg, tf, last, alpha, wz = ctx.saved_tensors
        grads = load_extension().backward3d(means2d, conics, opacities, f, offsets, ids, box, bg, tf, last, alpha, wz,
                                            _grad(g_rgb), _grad(g_alpha), _grad(g_depth), *ctx.dims)
        return (*grads, None, None, None, None, None, None, None, None)


def _background(bg: Tensor | None, like: Tensor) -> Tensor:
    if bg is None:
        return like.new_empty(0)
    if bg.requires_grad:
        raise ValueError("fused rasteriser: the background is a constant (requires_grad background: use impl=torch)")
    return bg.to(like).contiguous()


def composite3d(means2d: Tensor, conics: Tensor, opacities: Tensor, colors: Tensor, depth: Tensor, offsets: Tensor,
                ids: Tensor, C: int, H: int, W: int, tile: int, box: Tensor,
                background: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Composite sorted 3-D Gaussians front to back (the outputs of ``render_3dgs``).

    Args:
        means2d: ``[M, 2]`` pixel centres of the ``M = C*N`` (camera, splat) entries.
        conics: ``[M, 3]`` inverse 2-D covariance ``(a, b, c)``: power = -0.5(a dx^2 + c dy^2) - b dx dy.
        opacities: ``[M]``; colors ``[M, 3]``; depth ``[M]`` centre depth (composited into the depth map).
        offsets: ``[C*TY*TX + 1]`` int64 start of each (camera, tile) in ``ids``; ids: ``[P]`` int64 into M,
            sorted by depth within each tile.
        box: ``[M, 4]`` int64 inclusive pixel box ``(x0, x1, y0, y1)`` outside which the splat's alpha is
            below 1/255 (pixels outside are skipped without evaluation).
        background: ``[3]`` constant composited as ``rgb + (1 - alpha) bg`` (None: none).
    Returns:
        rgb ``[C, H, W, 3]``, alpha ``[C, H, W, 1]``, depth ``[C, H, W, 1]`` (``sum w z / alpha``, 0 where alpha = 0).
    """
    c = lambda t: t.contiguous()
    return _Composite3D.apply(c(means2d), c(conics), c(opacities), c(colors), c(depth), c(offsets), c(ids), c(box),
                              _background(background, colors), C, H, W, tile)


class _Composite2D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, Hm, Dz, centers, opacities, colors, normals, mcoef, offsets, ids, box, bg, near, inv2, C, H, W,
                tile):
        rgb, normal, alpha, depth, med, dist, f, tf, m1, m2, mref, last, medi, dsum = load_extension().forward2d(
            Hm, Dz, centers, opacities, colors, normals, mcoef, offsets, ids, box, bg, near, inv2, C, H, W, tile)
        ctx.save_for_backward(Hm, Dz, centers, opacities, f, mcoef, offsets, ids, box, bg, tf, m1, m2, mref, last,
                              medi, alpha, dsum)
        ctx.dims = (near, inv2, C, H, W, tile)
        ctx.set_materialize_grads(False)
        return rgb, normal, alpha, depth, med, dist

    @staticmethod
    def backward(ctx, *g):
        Hm, Dz, centers, opacities, f, mcoef, offsets, ids, box, bg, *saved = ctx.saved_tensors
        grads = load_extension().backward2d(Hm, Dz, centers, opacities, f, mcoef, offsets, ids, box, bg, *ctx.dims,
                                            *saved, *(_grad(x) for x in g))
        return (*grads, None, None, None, None, None, None, None, None, None, None, None)


def composite2d(Hm: Tensor, Dz: Tensor, centers: Tensor, opacities: Tensor, colors: Tensor, normals: Tensor,
                mcoef: Tensor, offsets: Tensor, ids: Tensor, near: float, C: int, H: int, W: int, tile: int, box: Tensor,
                background: Tensor | None = None, lowpass_sigma: float = 2**-0.5):
    """Composite sorted 2-D Gaussian surfels front to back (official 2DGS rules, see cpp/composite2d.cpp).

    Args:
        Hm: ``[M, 9]`` homography rows Tu, Tv, Tw per (camera, splat) entry; Dz: ``[M, 3]`` camera-z row;
        centers: ``[M, 2]`` projected centres (low-pass filter); opacities ``[M]``; colors, normals ``[M, 3]``;
        mcoef: ``[C, 3]`` normalised depth m = m0 + m1 z + m2 / z of the distortion term;
        offsets, ids, box: tile ranges and pixel boxes as in :func:`composite3d`; near: minimum depth;
        background: ``[3]`` constant or None; lowpass_sigma: sigma (pixels) of the screen-space low-pass filter
        (``rho2d = |pixel - centre|^2 / sigma^2``; official ``1/sqrt(2)``).
    Returns:
        rgb ``[C,H,W,3]``, normal ``[C,H,W,3]`` (``sum w n``), alpha, depth (``sum w z / alpha``), median depth,
        distortion ``[C,H,W,1]``.
    """
    c = lambda t: t.contiguous()
    return _Composite2D.apply(c(Hm), c(Dz), c(centers), c(opacities), c(colors), c(normals), c(mcoef), c(offsets),
                              c(ids), c(box), _background(background, colors), float(near),
                              1.0 / float(lowpass_sigma) ** 2, C, H, W, tile)


class _Project2D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, leaf, P, view, ortho):
        outs = load_extension().project2d_forward(means, quats, scales, P, view, ortho)
        ctx.save_for_backward(means, quats, scales, P, view)
        ctx.ortho, ctx.leaf_shape = ortho, leaf.shape
        return tuple(outs)

    @staticmethod
    def backward(ctx, g_H, g_Dz, g_centre, g_normal):
        means, quats, scales, P, view = ctx.saved_tensors
        gm, gq, gs, gsh = load_extension().project2d_backward(
            means, quats, scales, P, view, ctx.ortho, *(g.contiguous() for g in (g_H, g_Dz, g_centre, g_normal)))
        return gm, gq, gs, gsh.reshape(ctx.leaf_shape), None, None, None


def project_2dgs(means: Tensor, quats: Tensor, scales: Tensor, leaf: Tensor, P: Tensor, view: Tensor, ortho: bool):
    """Fused 2DGS projection (``splat_homographies`` + ``camera_facing_normals`` + screen shift, gs2d/render.py).

    Args: means ``[N, 3]``, quats ``[N, 4]``, scales ``[N, 2]``; leaf ``[C, N, 2]`` screen-position leaf (its value
        is not read: it enters as a zero shift, its gradient is the screen-position gradient); P ``[C, 4, 4]``
        (:func:`pixel_projection`); view ``[C, 3]`` camera forward (orthographic) or centre (pinhole).
    Returns: H ``[C*N, 9]`` rows Tu, Tv, Tw; Dz ``[C*N, 3]`` row Tz; centre ``[C*N, 2]``; normals ``[C*N, 3]``.
    """
    c = lambda t: t.contiguous()
    return _Project2D.apply(c(means), c(quats), c(scales), leaf, c(P), c(view), bool(ortho))


class _Project3D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, leaf, P, near):
        m2, depth, conics, cov = load_extension().project3d_forward(means, quats, scales, P, near)
        ctx.save_for_backward(means, quats, scales, P)
        ctx.near, ctx.leaf_shape = near, leaf.shape
        ctx.mark_non_differentiable(cov)
        return m2, depth, conics, cov

    @staticmethod
    def backward(ctx, g_m2, g_depth, g_conics, _g_cov):
        means, quats, scales, P = ctx.saved_tensors
        gm, gq, gs, gsh = load_extension().project3d_backward(
            means, quats, scales, P, ctx.near, *(g.contiguous() for g in (g_m2, g_depth, g_conics)))
        return gm, gq, gs, gsh.reshape(ctx.leaf_shape), None, None


def project_3dgs(means: Tensor, quats: Tensor, scales: Tensor, leaf: Tensor, P: Tensor, near: float):
    """Fused 3DGS EWA projection (``project_gaussians`` + conics of ``render_3dgs``, gs3d/render.py).

    Args: means ``[N, 3]``, quats ``[N, 4]``, scales ``[N, 3]``; leaf ``[C, N, 2]`` as in :func:`project_2dgs`;
        P ``[C, 4, 4]``; near: conics of centres at depth ``<= near`` are not inverted (culled anyway).
    Returns: means2d ``[C*N, 2]``, depth ``[C*N]``, conics ``[C*N, 3]``, cov ``[C*N, 3]`` (a, b, c; no gradient).
    """
    c = lambda t: t.contiguous()
    return _Project3D.apply(c(means), c(quats), c(scales), leaf, c(P), float(near))


@torch.no_grad()
def footprint_bin_2dgs(H: Tensor, Dz: Tensor, opacities: Tensor, C: int, near: float, W: int, Hh: int, tile: int,
                       lowpass_sigma: float = 2**-0.5):
    """``footprint_2dgs`` + ``bin_tiles`` fused: radii ``[C*N]`` (0 where not visible), visible ``[C*N]``,
    rects ``[C*N, 4]``, effective pixel boxes ``[C*N, 4]``, tile offsets ``[C*TY*TX + 1]``, sorted ids ``[P]``."""
    return load_extension().footprint_bin2d(H.contiguous(), Dz.contiguous(), opacities.contiguous(), C, float(near),
                                            W, Hh, tile, float(lowpass_sigma))


@torch.no_grad()
def footprint_bin_3dgs(means2d: Tensor, depth: Tensor, cov: Tensor, opacities: Tensor, C: int, near: float, W: int,
                       H: int, tile: int):
    """``footprint_3dgs`` + ``bin_tiles`` fused; returns as :func:`footprint_bin_2dgs`."""
    c = lambda t: t.contiguous()
    return load_extension().footprint_bin3d(c(means2d), c(depth), c(cov), c(opacities), C, float(near), W, H, tile)


if __name__ == "__main__":  # `python -m arcsem.backbones.gaussians.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = load_extension(verbose=False) is not None
    print(f"fused C++ rasteriser: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
