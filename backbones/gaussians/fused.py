"""Fused C++ CPU compositing kernels (forward + backward), built as a PyTorch JIT extension.

The kernels in ``cpp/`` replace only the per-pixel front-to-back loop; projection, binning and
sorting stay in PyTorch, so autograd chains through them unchanged. The PyTorch compositor is the
reference: tests/test_fused.py checks values and gradients of both paths against each other.

``load_extension()`` compiles once (about a minute with gcc; cached under
``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``) and returns None with one warning when
the toolchain is missing, so ``rasterizer: auto`` falls back to PyTorch.
"""
from __future__ import annotations

import os
import warnings
from functools import lru_cache
from pathlib import Path

import torch
from torch import Tensor

__all__ = [
    "composite2d",
    "composite3d",
    "composite_2dgs_packed",
    "composite_3dgs_packed",
    "load_extension",
    "resolve_impl",
]

SOURCES = [Path(__file__).parent / "cpp" / name for name in ("composite3d.cpp", "composite2d.cpp", "module.cpp")]


@lru_cache(maxsize=1)
def load_extension(verbose: bool = False):
    """The compiled module, or None (with one warning) when it cannot be built or loaded."""
    if os.environ.get("ARCSEM_NO_CPP"):
        return None
    try:
        from torch.utils.cpp_extension import load

        return load(
            name="arcsem_fused_raster",
            sources=[str(s) for s in SOURCES if s.exists()],
            extra_cflags=["-O3", "-fopenmp"],
            extra_ldflags=["-fopenmp"],
            verbose=verbose,
        )
    except Exception as exc:  # noqa: BLE001 - no compiler, no headers, ...: fall back, say it once
        warnings.warn(f"arcsem: fused C++ rasteriser unavailable ({type(exc).__name__}: {str(exc)[:200]}); "
                      "using the PyTorch path (rasterizer=torch)", RuntimeWarning, stacklevel=2)
        return None


def resolve_impl(impl: str) -> str:
    """``auto`` -> ``cpp`` if the extension loads (CPU tensors), else ``torch``; ``cpp`` must load."""
    if impl not in ("auto", "torch", "cpp"):
        from arcsem.errors import ConfigError

        raise ConfigError(f"rasterizer: '{impl}' is not one of auto, torch, cpp")
    if impl == "torch":
        return "torch"
    ok = load_extension() is not None
    if impl == "cpp" and not ok:
        from arcsem.errors import ConfigError

        raise ConfigError("rasterizer: 'cpp' requested but the C++ extension could not be built (see warning)")
    return "cpp" if ok else "torch"


class _Composite3D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, offsets, ids, box, C, H, W, tile):
        ext = load_extension()
        out, t_final, alpha, last = ext.forward3d(means2d, conics, opacities, feats, offsets, ids, box, C, H, W, tile)
        ctx.save_for_backward(means2d, conics, opacities, feats, offsets, ids, box, t_final, last)
        ctx.dims = (C, H, W, tile)
        ctx.mark_non_differentiable(last)
        return out, alpha, last

    @staticmethod
    def backward(ctx, g_out, g_alpha, _g_last):
        means2d, conics, opacities, feats, offsets, ids, box, t_final, last = ctx.saved_tensors
        grads = load_extension().backward3d(
            means2d, conics, opacities, feats, offsets, ids, box, t_final, last,
            g_out.contiguous(), g_alpha.contiguous(), *ctx.dims,
        )
        return (*grads, None, None, None, None, None, None, None)


def _full_box(M: int, W: int, H: int, like: Tensor) -> Tensor:
    return torch.tensor([0, W - 1, 0, H - 1], dtype=torch.long, device=like.device).expand(M, 4).contiguous()


def composite3d(means2d: Tensor, conics: Tensor, opacities: Tensor, feats: Tensor, offsets: Tensor, ids: Tensor,
                C: int, H: int, W: int, tile: int = 16, box: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Composite sorted 3-D Gaussians front to back.

    Args:
        means2d: ``[M, 2]`` pixel centres of the ``M = C*N`` (camera, splat) entries.
        conics: ``[M, 3]`` inverse 2-D covariance ``(a, b, c)``: power = -0.5(a dx^2 + c dy^2) - b dx dy.
        opacities: ``[M]``; feats: ``[M, K]`` features composited with the weights (colour, depth, ...).
        offsets: ``[C*TY*TX + 1]`` int64 start of each (camera, tile) in ``ids``; ids: ``[P]`` int64 into M,
            sorted by depth within each tile.
        box: ``[M, 4]`` int64 inclusive pixel box ``(x0, x1, y0, y1)`` outside which the splat's alpha is
            below 1/255 (pixels outside are skipped without evaluation); None = whole image.
    Returns:
        features ``[C, H, W, K]`` (no background) and alpha ``[C, H, W]``.
    """
    box = _full_box(feats.shape[0], W, H, feats) if box is None else box
    out, alpha, _ = _Composite3D.apply(
        means2d.contiguous(), conics.contiguous(), opacities.contiguous(), feats.contiguous(),
        offsets.contiguous(), ids.contiguous(), box.contiguous(), C, H, W, tile,
    )
    return out, alpha


class _Composite2D(torch.autograd.Function):
    @staticmethod
    def forward(ctx, Hm, Dz, centers, opacities, feats, mcoef, offsets, ids, box, near, C, H, W, tile):
        ext = load_extension()
        out, tf, alpha, dsum, med, dist, m1, m2, mref, last, medi = ext.forward2d(
            Hm, Dz, centers, opacities, feats, mcoef, offsets, ids, box, near, C, H, W, tile)
        ctx.save_for_backward(Hm, Dz, centers, opacities, feats, mcoef, offsets, ids, box, tf, m1, m2, mref, last,
                              medi)
        ctx.dims = (near, C, H, W, tile)
        return out, alpha, dsum, med, dist

    @staticmethod
    def backward(ctx, g_out, g_alpha, g_dsum, g_med, g_dist):
        Hm, Dz, centers, opacities, feats, mcoef, offsets, ids, box, tf, m1, m2, mref, last, medi = ctx.saved_tensors
        grads = load_extension().backward2d(
            Hm, Dz, centers, opacities, feats, mcoef, offsets, ids, box, *ctx.dims, tf, m1, m2, mref, last, medi,
            *(g.contiguous() for g in (g_out, g_alpha, g_dsum, g_med, g_dist)))
        return (*grads, None, None, None, None, None, None, None, None, None)


def composite2d(Hm: Tensor, Dz: Tensor, centers: Tensor, opacities: Tensor, feats: Tensor, mcoef: Tensor,
                offsets: Tensor, ids: Tensor, near: float, C: int, H: int, W: int, tile: int = 16,
                box: Tensor | None = None):
    """Composite sorted 2-D Gaussian surfels front to back (official 2DGS rules, see cpp/composite2d.cpp).

    Args:
        Hm: ``[M, 9]`` homography rows Tu, Tv, Tw per (camera, splat) entry; Dz: ``[M, 3]`` camera-z row;
        centers: ``[M, 2]`` projected centres (low-pass filter); opacities ``[M]``; feats ``[M, K]``;
        mcoef: ``[C, 3]`` normalised depth m = m0 + m1 z + m2 / z of the distortion term;
        offsets, ids, box: tile ranges and pixel boxes as in :func:`composite3d`; near: minimum depth.
    Returns:
        features ``[C,H,W,K]``, alpha ``[C,H,W]``, depth sum ``sum w z`` ``[C,H,W]``, median depth ``[C,H,W]``,
        distortion ``[C,H,W]``.
    """
    c = lambda t: t.contiguous()
    box = _full_box(feats.shape[0], W, H, feats) if box is None else box
    return _Composite2D.apply(c(Hm), c(Dz), c(centers), c(opacities), c(feats), c(mcoef), c(offsets), c(ids),
                              c(box), float(near), C, H, W, tile)



def composite_2dgs_packed(Hm: Tensor, centre2d: Tensor, opacities: Tensor, feats: Tensor, binning, box: Tensor,
                          dist_near: float, dist_far: float) -> Tensor:
    """The 2DGS torch shader's packed per-pixel output, from the fused kernel.

    Args: Hm ``[C*N, 4, 3]`` rows Tu, Tv, Tw, Tz; centre2d ``[C*N, 2]``; opacities ``[C*N]``;
        feats ``[C*N, 6]`` (colour, normal); binning: :class:`~arcsem.backbones.gaussians.raster.Binning`;
        box: ``[C*N, 4]`` effective pixel boxes of the torch path.
    Returns: ``[C, H, W, 10]`` = rgb(3), alpha, sum w z, normal(3), distortion, median depth.
    """
    b = binning
    a = dist_far / (dist_far - dist_near)  # m = a (1 - near / z) = a - a near / z
    mcoef = Hm.new_tensor([a, 0.0, -a * dist_near]).expand(b.C, 3)
    f, alpha, dsum, med, dist = composite2d(
        Hm[:, :3, :].reshape(-1, 9), Hm[:, 3, :], centre2d, opacities, feats, mcoef, b.offsets, b.splat,
        float("-inf"), b.C, b.H, b.W, b.tile, box)
    return torch.cat([f[..., :3], alpha[..., None], dsum[..., None], f[..., 3:6], dist[..., None],
                      med[..., None]], -1)


def composite_3dgs_packed(means2d: Tensor, conics: Tensor, opacities: Tensor, feats: Tensor, binning,
                          box: Tensor) -> Tensor:
    """The 3DGS torch shader's packed output ``[C, H, W, K + 1]`` = features (colour, depth), alpha."""
    b = binning
    f, alpha = composite3d(means2d, conics, opacities, feats, b.offsets, b.splat, b.C, b.H, b.W, b.tile, box)
    return torch.cat([f, alpha[..., None]], -1)


if __name__ == "__main__":  # `python -m arcsem.backbones.gaussians.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = load_extension(verbose=False) is not None
    print(f"fused C++ rasteriser: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
