"""Fused C++ CPU compositing kernels (forward + backward), built as a PyTorch JIT extension.

The kernels in ``cpp/`` cover the whole ``rasterizer: cpp`` pipeline in a few calls (on a shared,
oversubscribed 2-core machine every multi-threaded PyTorch op can cost a scheduler slice, so op count
matters as much as arithmetic): the differentiable projection (``project.cpp``: 2DGS homographies and
normals; ``project3d.cpp``: 3DGS EWA conics; with backward kernels), footprints + tile binning + depth sort
(``binning.cpp``, no gradient), the front-to-back compositing (``composite2d.cpp``, ``composite3d.cpp``) and the
densification statistics (``stats.cpp``). The PyTorch
path is the reference: tests/test_fused.py checks values and gradients of both paths against each other.

``load_extension()`` compiles once (about a minute with gcc; cached under
``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``) and returns None with one warning when
the toolchain is missing, so ``rasterizer: auto`` falls back to PyTorch.
"""
from __future__ import annotations

import platform
from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext

from .config import LOWPASS_SIGMA

__all__ = [
    "EXTENSION",
    "act_rows",
    "composite2d",
    "composite3d",
    "composite_weights",
    "footprint_bin_2dgs",
    "footprint_bin_3dgs",
    "load_extension",
    "project_2dgs",
    "project_3dgs",
    "resolve_impl",
    "sh_colors",
]

CPP_DIR = Path(__file__).parent / "cpp"
EXTENSION = cext.Extension(
    prefix="arcsem_fused_raster",
    sources=tuple(CPP_DIR / n for n in ("composite3d.cpp", "composite2d.cpp", "composite2d_backward.cpp", "binning.cpp",
                                        "project.cpp", "project3d.cpp", "sh.cpp", "stats.cpp", "weights.cpp", "pool.cpp",
                                        "module.cpp")),
    what="fused C++ Gaussian rasteriser",
    # the lane loops of the compositing kernels (`omp simd`) vectorise only when GCC may if-convert freely: no FP traps
    # (the kernels do not use them), no errno from std::sqrt (the SH kernel's lanes), and no partial-redundancy
    # elimination hoisting loads into branches. A 16-pixel lane
    # block is one 512-bit register where the CPU has them (GCC's default for these CPUs is 256-bit vectors): the
    # 2DGS compositing 13 % faster on two threads, measured (benchmarks/results/README.md); an x86 option, a no-op on
    # x86 CPUs without AVX-512
    cflags=(*cext.NATIVE_CFLAGS, "-fno-trapping-math", "-fno-math-errno", "-fno-tree-pre",
            *(("-mprefer-vector-width=512",) if platform.machine().lower() in ("x86_64", "amd64") else ())),
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


def _args(kind: str, **fields):
    """The kernels' argument struct ``kind`` (cpp/api.h) with its fields set by name."""
    s = getattr(load_extension(), kind)()
    for k, v in fields.items():
        setattr(s, k, v)
    return s


def _raster(C: int, H: int, W: int, tile: int):
    return _args("Raster", C=int(C), H=int(H), W=int(W), tile=int(tile))


class _Composite3D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depth, bg, lists, raster):
        splats = _args("Splats3D", means2d=means2d, conics=conics, opacities=opacities, colors=colors, depth=depth,
                       background=bg)
        res = load_extension().composite3d_forward(splats, lists, raster)
        ctx.save_for_backward(means2d, conics, opacities, colors, depth, bg, res.pairs, res.t_final, res.wz, res.last,
                              res.alpha)
        ctx.lists, ctx.raster = lists, raster
        ctx.set_materialize_grads(False)
        return res.rgb, res.alpha, res.depth

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_depth):
        means2d, conics, opacities, colors, depth, bg, pairs, t_final, wz, last, alpha = ctx.saved_tensors
        splats = _args("Splats3D", means2d=means2d, conics=conics, opacities=opacities, colors=colors, depth=depth,
                       background=bg)
        fwd = _args("Composite3D", pairs=pairs, t_final=t_final, wz=wz, last=last, alpha=alpha)
        g = load_extension().composite3d_backward(splats, ctx.lists, ctx.raster, fwd, _grad(g_rgb), _grad(g_alpha),
                                                  _grad(g_depth))
        return g.means2d, g.conics, g.opacities, g.colors, g.depth, None, None, None


def _background(bg: Tensor | None, like: Tensor) -> Tensor:
    if bg is None:
        return like.new_empty(0)
    if bg.requires_grad:
        raise ValueError("fused rasteriser: the background is a constant (requires_grad background: use impl=torch)")
    return bg.to(like).contiguous()


def composite3d(means2d: Tensor, conics: Tensor, opacities: Tensor, colors: Tensor, depth: Tensor, lists,
                C: int, H: int, W: int, tile: int, background: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Composite sorted 3-D Gaussians front to back (the outputs of ``render_3dgs``).

    Args:
        means2d: ``[M, 2]`` pixel centres of the ``M = C*N`` (camera, splat) entries.
        conics: ``[M, 3]`` inverse 2-D covariance ``(a, b, c)``: power = -0.5(a dx^2 + c dy^2) - b dx dy.
        opacities: ``[M]``; colors ``[M, 3]``; depth ``[M]`` centre depth (composited into the depth map).
        lists: the tile lists of :func:`footprint_bin_3dgs` (sorted pairs, pixel boxes outside which alpha < 1/255).
        background: ``[3]`` constant composited as ``rgb + (1 - alpha) bg`` (None: none).
    Returns:
        rgb ``[C, H, W, 3]``, alpha ``[C, H, W, 1]``, depth ``[C, H, W, 1]`` (``sum w z / alpha``, 0 where alpha = 0).
    """
    c = lambda t: t.contiguous()
    return _Composite3D.apply(c(means2d), c(conics), c(opacities), c(colors), c(depth), _background(background, colors),
                              lists, _raster(C, H, W, tile))


_SURFEL_FIELDS = ("H", "Dz", "centres", "opacities", "colors", "normals", "mcoef", "background")


class _Composite2D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, Hm, Dz, centres, opacities, colors, normals, mcoef, bg, near, lowpass, lists, raster):
        inputs = (Hm, Dz, centres, opacities, colors, normals, mcoef, bg)
        surfels = _args("Surfels2D", **dict(zip(_SURFEL_FIELDS, inputs)), near=near, lowpass=lowpass)
        r = load_extension().composite2d_forward(surfels, lists, raster)
        ctx.save_for_backward(*inputs, r.pairs, r.t_final, r.wz, r.m1, r.m2, r.mref, r.last, r.median_pair, r.alpha)
        ctx.near, ctx.lowpass, ctx.lists, ctx.raster = near, lowpass, lists, raster
        ctx.set_materialize_grads(False)
        return r.rgb, r.normal, r.alpha, r.depth, r.median, r.distortion

    @staticmethod
    def backward(ctx, *g):
        saved = ctx.saved_tensors
        surfels = _args("Surfels2D", **dict(zip(_SURFEL_FIELDS, saved[:8])), near=ctx.near, lowpass=ctx.lowpass)
        fwd = _args("Composite2D", **dict(zip(("pairs", "t_final", "wz", "m1", "m2", "mref", "last", "median_pair",
                                                "alpha"), saved[8:])))
        # frozen geometry (stage 2): only the colour gradient is computed
        geometry = any(ctx.needs_input_grad[i] for i in (0, 1, 2, 3, 5))
        r = load_extension().composite2d_backward(surfels, ctx.lists, ctx.raster, fwd, *(_grad(x) for x in g),
                                                  geometry=geometry)
        if not geometry:
            return None, None, None, None, r.colors, None, None, None, None, None, None, None
        return r.H, r.Dz, r.centres, r.opacities, r.colors, r.normals, None, None, None, None, None, None


def composite2d(Hm: Tensor, Dz: Tensor, centers: Tensor, opacities: Tensor, colors: Tensor, normals: Tensor,
                mcoef: Tensor, lists, near: float, C: int, H: int, W: int, tile: int,
                background: Tensor | None = None, lowpass_sigma: float = LOWPASS_SIGMA):
    """Composite sorted 2-D Gaussian surfels front to back (official 2DGS rules, see cpp/composite2d.h).

    Args:
        Hm: ``[M, 9]`` homography rows Tu, Tv, Tw per (camera, splat) entry; Dz: ``[M, 3]`` camera-z row;
        centers: ``[M, 2]`` projected centres (low-pass filter); opacities ``[M]``; colors, normals ``[M, 3]``;
        mcoef: ``[C, 3]`` normalised depth m = m0 + m1 z + m2 / z of the distortion term;
        lists: the tile lists of :func:`footprint_bin_2dgs`; near: minimum depth;
        background: ``[3]`` constant or None; lowpass_sigma: sigma (pixels) of the screen-space low-pass filter
        (``rho2d = |pixel - centre|^2 / sigma^2``; official ``1/sqrt(2)``).
    Returns:
        rgb ``[C,H,W,3]``, normal ``[C,H,W,3]`` (``sum w n``), alpha, depth (``sum w z / alpha``), median depth,
        distortion ``[C,H,W,1]``.
    """
    c = lambda t: t.contiguous()
    return _Composite2D.apply(c(Hm), c(Dz), c(centers), c(opacities), c(colors), c(normals), c(mcoef),
                              _background(background, colors), float(near), 1.0 / float(lowpass_sigma) ** 2, lists,
                              _raster(C, H, W, tile))


def composite_weights(kind: str, *inputs: Tensor, lists, C: int, H: int, W: int, tile: int, near: float = 0.0,
                      lowpass_sigma: float = LOWPASS_SIGMA):
    """The weights ``w = alpha T`` with which the forward pass of :func:`composite2d` (``kind="2d"``: ``inputs`` its
    ``Hm, Dz, centers, opacities, colors, normals, mcoef``) or :func:`composite3d` (``"3d"``: ``means2d, conics,
    opacities, colors, depth``) composites each (pixel, pair): a frozen geometry's render is ``W colors[lists.ids]
    + T_final bg`` (cpp/weights.h). No gradient. Returns a namespace: CSR over the ``C*H*W`` pixels (``pix_ptr``,
    ``pix_pair``, ``pix_w``), ``t_final [C*H*W]``, ``ids [P]`` (the entry of each of the ``P`` pairs), ``transpose``
    (``g [C*H*W, 3] -> W^T g [P, 3]``, a kernel of its own: no transposed copy is kept) and ``nbytes``."""
    from types import SimpleNamespace

    c = [t.detach().contiguous() for t in inputs]
    bg = c[0].new_empty(0)
    raster, ext = _raster(C, H, W, tile), load_extension()
    with torch.no_grad():
        if kind == "2d":
            surfels = _args("Surfels2D", **dict(zip(_SURFEL_FIELDS, (*c, bg))), near=float(near),
                            lowpass=1.0 / float(lowpass_sigma) ** 2)
            r = ext.composite2d_weights(surfels, lists, raster)
        elif kind == "3d":
            splats = _args("Splats3D", **dict(zip(("means2d", "conics", "opacities", "colors", "depth", "background"),
                                                  (*c, bg))))
            r = ext.composite3d_weights(splats, lists, raster)
        else:
            raise ValueError(f"composite_weights: kind must be 2d or 3d, got {kind!r}")
    held = (r.pix_ptr, r.pix_pair, r.pix_w, lists.ids)
    return SimpleNamespace(pix_ptr=r.pix_ptr, pix_pair=r.pix_pair, pix_w=r.pix_w, t_final=r.t_final, ids=lists.ids,
                           transpose=lambda g: ext.weights_backward(r, raster, g.contiguous()),
                           nbytes=sum(t.numel() * t.element_size() for t in held))


def _projection(means, quats, scales, P, view=None, ortho=False, near=0.01):
    return _args("Projection", means=means, quats=quats, scales=scales, P=P,
                 view=view if view is not None else P.new_empty(0), ortho=bool(ortho), near=float(near))


class _Project2D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, leaf, P, view, ortho):
        outs = load_extension().project2d_forward(_projection(means, quats, scales, P, view, ortho))
        ctx.save_for_backward(means, quats, scales, P, view)
        ctx.ortho, ctx.leaf_shape = ortho, leaf.shape
        return tuple(outs)

    @staticmethod
    def backward(ctx, g_H, g_Dz, g_centre, g_normal):
        means, quats, scales, P, view = ctx.saved_tensors
        gm, gq, gs, gsh = load_extension().project2d_backward(
            _projection(means, quats, scales, P, view, ctx.ortho), *(g.contiguous() for g in (g_H, g_Dz, g_centre, g_normal)))
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
        m2, depth, conics, cov = load_extension().project3d_forward(_projection(means, quats, scales, P, near=near))
        ctx.save_for_backward(means, quats, scales, P)
        ctx.near, ctx.leaf_shape = near, leaf.shape
        ctx.mark_non_differentiable(cov)
        return m2, depth, conics, cov

    @staticmethod
    def backward(ctx, g_m2, g_depth, g_conics, _g_cov):
        means, quats, scales, P = ctx.saved_tensors
        gm, gq, gs, gsh = load_extension().project3d_backward(
            _projection(means, quats, scales, P, near=ctx.near), *(g.contiguous() for g in (g_m2, g_depth, g_conics)))
        return gm, gq, gs, gsh.reshape(ctx.leaf_shape), None, None


def project_3dgs(means: Tensor, quats: Tensor, scales: Tensor, leaf: Tensor, P: Tensor, near: float):
    """Fused 3DGS EWA projection (``project_gaussians`` + conics of ``render_3dgs``, gs3d/render.py).

    Args: means ``[N, 3]``, quats ``[N, 4]``, scales ``[N, 3]``; leaf ``[C, N, 2]`` as in :func:`project_2dgs`;
        P ``[C, 4, 4]``; near: conics of centres at depth ``<= near`` are not inverted (culled anyway).
    Returns: means2d ``[C*N, 2]``, depth ``[C*N]``, conics ``[C*N, 3]``, cov ``[C*N, 3]`` (a, b, c; no gradient).
    """
    c = lambda t: t.contiguous()
    return _Project3D.apply(c(means), c(quats), c(scales), leaf, c(P), float(near))


class _ShColors(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, sh_dc, sh_rest, origins, act_w, act_b, ortho, degree):
        args = _args("ShColors", means=means, sh_dc=sh_dc, sh_rest=sh_rest, origins=origins, act_w=act_w, act_b=act_b,
                     ortho=ortho, degree=degree)
        ctx.save_for_backward(means, sh_dc, sh_rest, origins, act_w, act_b)
        ctx.ortho, ctx.degree = ortho, degree
        return load_extension().sh_colors_forward(args)

    @staticmethod
    def backward(ctx, g):
        means, sh_dc, sh_rest, origins, act_w, act_b = ctx.saved_tensors
        args = _args("ShColors", means=means, sh_dc=sh_dc, sh_rest=sh_rest, origins=origins, act_w=act_w, act_b=act_b,
                     ortho=ctx.ortho, degree=ctx.degree)
        gm, gdc, grest, gw, gb = load_extension().sh_colors_backward(args, g)
        # degree 0 reads no rest coefficient and no direction: no gradient, as the PyTorch path
        return (gm if ctx.degree > 0 else None), gdc, (grest if ctx.degree > 0 else None), None, gw, gb, None, None


def sh_colors(means: Tensor, sh_dc: Tensor, sh_rest: Tensor, origins: Tensor, ortho: bool, degree: int,
              act: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Fused ``max(eval_sh(degree, sh, view direction) + 0.5, 0)`` of every (camera, splat) (sh.py is the reference),
    with ``act = (w, b)`` then ``clamp(w[c] * rgb + b[c], 0, 1)`` per camera (ACT.apply is the reference).

    Args: means ``[N, 3]``; sh_dc ``[N, 1, 3]``; sh_rest ``[N, R, 3]``; origins ``[C, 3]``: camera centres (pinhole,
        direction ``mean - centre``) or forward axes (orthographic); degree 0..3; act: w, b ``[C, 3]`` or ``[C, 1]``
        (broadcast over the channels; :meth:`ACT.transforms`), or None.
    Returns: ``[C, N, 3]``.
    """
    c = lambda t: t.contiguous()
    w, b = act_rows(means, origins, act)
    return _ShColors.apply(c(means), c(sh_dc), c(sh_rest), c(origins.to(means.dtype)), w, b, bool(ortho), int(degree))


def act_rows(means: Tensor, origins: Tensor, act: tuple[Tensor, Tensor] | None) -> tuple[Tensor, Tensor]:
    """ACT's ``w, b`` as the SH colour kernels read them: ``[C, 3]`` contiguous in the means' dtype (empty: no ACT)."""
    if act is None:
        return means.new_empty(0), means.new_empty(0)
    C = origins.shape[0]
    return tuple(t.to(means.dtype).expand(C, 3).contiguous() for t in act)


@torch.no_grad()
def footprint_bin_2dgs(H: Tensor, Dz: Tensor, opacities: Tensor, C: int, near: float, W: int, Hh: int, tile: int,
                       lowpass_sigma: float = LOWPASS_SIGMA):
    """``footprint_2dgs`` + ``bin_tiles`` fused: the tile lists (cpp/api.h ``TileLists``): radii ``[C*N]`` (0 where
    not visible), visible ``[C*N]``, rects ``[C*N, 4]``, effective pixel boxes ``box [C*N, 4]``, tile ``offsets``
    ``[C*TY*TX + 1]``, sorted ``ids [P]``, and each entry's pairs (``entry_offsets``, ``pair_of``)."""
    return load_extension().footprint_bin2d(H.contiguous(), Dz.contiguous(), opacities.contiguous(),
                                            _raster(C, Hh, W, tile), float(near), float(lowpass_sigma))


@torch.no_grad()
def footprint_bin_3dgs(means2d: Tensor, depth: Tensor, cov: Tensor, opacities: Tensor, C: int, near: float, W: int,
                       H: int, tile: int):
    """``footprint_3dgs`` + ``bin_tiles`` fused; returns the tile lists as :func:`footprint_bin_2dgs`."""
    c = lambda t: t.contiguous()
    return load_extension().footprint_bin3d(c(means2d), c(depth), c(cov), c(opacities), _raster(C, H, W, tile),
                                            float(near))


@torch.no_grad()
def densify_stats(stats, grad_means: Tensor, means: Tensor, cams, visible: Tensor, radii: Tensor) -> None:
    """Add one step's densification statistics to ``stats`` (a ``DensifyStats``: float32 ``[N]`` accumulators) in
    one fused pass: ``stats.accumulate(screen_grad_norms(grad_means, means, cams), visible, radii)`` (densify.py, the
    reference). visible ``[C, N]`` bool, radii ``[C, N]``."""
    c = lambda t: t.contiguous()
    d = lambda t: t.to(torch.float64).contiguous()
    load_extension().densify_stats(_args(
        "DensifyStatsIn", grad_means=c(grad_means), means=c(means.to(grad_means.dtype)), w2c=d(cams.world_to_cam),
        K=d(cams.K), visible=c(visible.bool()), radii=c(radii.long()), grad_sum=stats.grad_sum, count=stats.count,
        max_radii=stats.max_radii, ortho=bool(cams.is_ortho), W=int(cams.width), H=int(cams.height)))


if __name__ == "__main__":  # `python -m arcsem.backbones.gaussians.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = load_extension(verbose=False) is not None
    print(f"fused C++ rasteriser: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
