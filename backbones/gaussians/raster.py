"""Projection-agnostic tile rasteriser: binning, (tile, depth) sort, chunked front-to-back compositing.

The semantics are those of the official 2DGS/3DGS CUDA rasterisers (Kerbl et al. 2023, Huang et al.
2024):

* a splat is considered by every pixel of every ``tile x tile`` tile touched by its screen rectangle
  (:func:`tile_rects`, the official ``getRect``), in the order of its centre depth (ties: index);
* ``alpha = min(0.99, opacity * G)``; a splat with ``alpha < 1/255`` is skipped;
* a pixel stops before the splat that would leave its transmittance ``T * (1 - alpha) < 1e-4``
  (that splat and every later one are not composited).

How it is vectorised (no Python loop over tiles or splats): splats are expanded to (camera-tile,
splat) pairs with a cumulative sum over tiles-per-splat and sorted by one int64 key
``camera_tile << 32 | depth_rank``. Pairs are processed in chunks of tiles. Inside a chunk each pair
is expanded to the pixels of its tile that lie inside the splat's *effective rectangle*: a box the
caller guarantees to contain every pixel where ``opacity * G >= 1/255`` (outside it the alpha would
be skipped anyway, so this changes nothing but the amount of work). Their alpha is evaluated without
gradient and the skipped ones dropped; the rest are stably sorted by pixel, so every pixel's splats
form one contiguous, depth-ordered segment. The transmittance is a segmented exclusive cumulative sum
of ``log(1 - alpha)`` (in float64; ``alpha <= 0.99`` keeps the logarithm finite); entries after the
early stop are dropped too, and only the composited entries go through the differentiable shader
(exact: the dropped ones have no value and no gradient). Everything is plain PyTorch, so autograd
gives the gradients; the fused C++ kernels (``fused.py``) are checked against this path.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = [
    "MAX_ALPHA",
    "MIN_ALPHA",
    "MIN_T",
    "Binning",
    "Segments",
    "bin_tiles",
    "composite",
    "composite_kept",
    "composited_mask",
    "effective_cutoff2",
    "raster_impl",
    "rasterize",
    "screen_position_leaf",
    "tile_rects",
]

MIN_ALPHA = 1.0 / 255.0  # skip splats fainter than this (official value)
MAX_ALPHA = 0.99  # clamp (keeps log(1 - alpha) finite)
MIN_T = 1e-4  # stop before the transmittance would fall below this
PAIR_PIXEL_BUDGET = 1 << 21  # pair-pixels per chunk when chunk_tiles is None (bounds memory)


@dataclass
class Binning:
    """(camera-tile, splat) pairs sorted by tile then depth.

    Attributes:
        splat: ``[P]`` long, index into the flattened ``[C*N]`` splats.
        ctile: ``[P]`` long, camera-tile id ``c * TY * TX + ty * TX + tx`` (non-decreasing).
        offsets: ``[C*TY*TX + 1]`` long, start of each camera-tile in the pair list.
        C, H, W, tile, TX, TY: sizes.
    """

    splat: Tensor
    ctile: Tensor
    offsets: Tensor
    C: int
    H: int
    W: int
    tile: int
    TX: int
    TY: int


def raster_impl(impl: str) -> str:
    """The path ``impl`` takes (2DGS and 3DGS alike): ``torch`` stays here (and ``triton``, 2DGS on Triton kernels
    for CUDA, resolved by the backbone); ``cpp`` / ``auto`` go through the fused-kernel loader
    (:func:`arcsem.backbones.gaussians.fused.resolve_impl`, which validates)."""
    if impl in ("torch", "triton"):
        return impl
    from arcsem.backbones.gaussians.fused import resolve_impl

    return resolve_impl(impl)


def effective_cutoff2(opacities: Tensor) -> Tensor:
    """``[...]`` squared Mahalanobis radius beyond which ``opacity * G < 1/255`` (with a safety margin).

    ``opacity * exp(-rho/2) >= 1/255  <=>  rho <= 2 ln(255 opacity)``; non-positive means never visible.
    """
    c2 = 2.0 * torch.log(255.0 * opacities.detach().double().clamp_min(1e-30))
    return c2 * (1 + 1e-4) + 1e-4


def tile_rects(center: Tensor, radius: Tensor, W: int, H: int, tile: int) -> Tensor:
    """Tile rectangle of each splat, as the official ``getRect`` (pixel centres at ``i + 0.5`` here).

    Args:
        center: ``[..., 2]`` screen centre in pixels; radius: ``[...]`` long, 0 = not rendered.
    Returns:
        ``[..., 4]`` long ``(tx0, tx1, ty0, ty1)``, upper bounds exclusive, clipped to the grid.
    """
    TX, TY = -(-W // tile), -(-H // tile)
    ok = radius > 0
    c = torch.where(ok[..., None], center.detach().double(), torch.zeros_like(center, dtype=torch.double)) - 0.5
    r = radius.double()
    big = 4.0 * (W + H + tile)  # keep the float->long conversion finite
    lo = ((c - r[..., None]) / tile).clamp(-big, big).floor().long()
    hi = ((c + r[..., None] + tile - 1) / tile).clamp(-big, big).floor().long()
    tx0, ty0 = lo[..., 0].clamp(0, TX), lo[..., 1].clamp(0, TY)
    tx1, ty1 = hi[..., 0].clamp(0, TX), hi[..., 1].clamp(0, TY)
    tx1, ty1 = torch.where(ok, tx1, tx0), torch.where(ok, ty1, ty0)
    return torch.stack([tx0, tx1, ty0, ty1], -1)


def bin_tiles(rects: Tensor, depth: Tensor, W: int, H: int, tile: int) -> Binning:
    """Expand splats to sorted (camera-tile, splat) pairs.

    Args:
        rects: ``[C, N, 4]`` long tile rectangles from :func:`tile_rects` (empty = not rendered).
        depth: ``[C, N]`` sort key (centre depth); ties keep the splat index order.
    """
    C, N = depth.shape
    TX, TY = -(-W // tile), -(-H // tile)
    dev = depth.device
    rank = torch.empty(C, N, dtype=torch.long, device=dev)
    order = torch.argsort(depth.detach(), dim=1, stable=True)
    rank.scatter_(1, order, torch.arange(N, device=dev).expand(C, N).contiguous())
    rects = rects.reshape(C * N, 4)
    nx = (rects[:, 1] - rects[:, 0]).clamp_min(0)
    ny = (rects[:, 3] - rects[:, 2]).clamp_min(0)
    count = nx * ny
    splat = torch.repeat_interleave(torch.arange(C * N, device=dev), count)
    start = torch.cumsum(count, 0) - count
    k = torch.arange(splat.numel(), device=dev) - start[splat]
    nxs = nx[splat]
    tx = rects[splat, 0] + k % nxs.clamp_min(1)
    ty = rects[splat, 2] + torch.div(k, nxs.clamp_min(1), rounding_mode="floor")
    cam = torch.div(splat, N, rounding_mode="floor")
    ctile = cam * (TX * TY) + ty * TX + tx
    key = (ctile << 32) | rank.reshape(-1)[splat]
    key, perm = torch.sort(key)
    splat, ctile = splat[perm], key >> 32
    offsets = torch.searchsorted(ctile, torch.arange(C * TX * TY + 1, device=dev))
    return Binning(splat, ctile, offsets, C, H, W, tile, TX, TY)


@dataclass
class Segments:
    """Pair-pixels grouped by pixel: every pixel's splats are one contiguous, depth-ordered segment.

    Attributes:
        seg: ``[Q]`` long segment (pixel) id per pair-pixel; start: ``[Q]`` index of its segment's first
        entry; n: number of segments; pixel: ``[n]`` long flat pixel id ``c*H*W + y*W + x``.
    """

    seg: Tensor
    start: Tensor
    n: int
    pixel: Tensor

    def excl_cumsum(self, x: Tensor) -> Tensor:
        """``[Q, ...]`` exclusive cumulative sum within each segment (accumulated in float64)."""
        xd = x.double()
        cs = torch.cumsum(xd, 0) - xd
        return (cs - torch.index_select(cs, 0, self.start)).to(x.dtype)

    def sum(self, x: Tensor) -> Tensor:
        """``[Q, K]`` -> ``[n, K]`` sum per segment."""
        return x.new_zeros(self.n, x.shape[1]).index_add(0, self.seg, x)

    def last(self, mask: Tensor) -> Tensor:
        """``[n]`` index of the last entry with ``mask`` in each segment, or -1."""
        pos = torch.where(mask, torch.arange(mask.numel(), device=mask.device), -1)
        out = torch.full((self.n,), -1, dtype=torch.long, device=mask.device)
        return out.scatter_reduce(0, self.seg, pos, reduce="amax", include_self=True)

    def select(self, mask: Tensor, idx: Tensor) -> Segments:
        """The entries where ``mask [Q]`` holds (at ``idx``), still grouped by the same ``n`` pixels."""
        seg = torch.index_select(self.seg, 0, idx)
        counts = torch.bincount(seg, minlength=self.n)
        return Segments(seg, torch.index_select(torch.cumsum(counts, 0) - counts, 0, seg), self.n, self.pixel)


def composite(alpha: Tensor, segs: Segments) -> tuple[Tensor, Tensor, Tensor]:
    """Front-to-back weights with the official skip / clamp / early-stop rules.

    Args:
        alpha: ``[Q]`` raw ``opacity * G`` of each pair-pixel, in segment (depth) order.
    Returns:
        w ``[Q]`` compositing weights ``alpha_i T_i`` (0 where not composited), T ``[Q]`` transmittance
        before each entry, keep ``[Q]`` bool (composited).
    """
    a = torch.where(alpha < MIN_ALPHA, torch.zeros_like(alpha), alpha.clamp(max=MAX_ALPHA))
    T = torch.exp(segs.excl_cumsum(torch.log1p(-a)))
    keep = (a > 0) & (T.detach() * (1 - a.detach()) >= MIN_T)
    w = torch.where(keep, a * T, torch.zeros_like(a))
    return w, T, keep


def composite_kept(alpha: Tensor, segs: Segments) -> tuple[Tensor, Tensor]:
    """:func:`composite` for entries already known to be composited (``composited_mask``): w, T ``[Q]``."""
    a = alpha.clamp(max=MAX_ALPHA)
    T = torch.exp(segs.excl_cumsum(torch.log1p(-a)))
    return a * T, T


@torch.no_grad()
def composited_mask(alpha: Tensor, segs: Segments) -> Tensor:
    """``[Q]`` bool: the entries :func:`composite` composites (not skipped, before the early stop)."""
    a = torch.where(alpha < MIN_ALPHA, torch.zeros_like(alpha), alpha.clamp(max=MAX_ALPHA))
    la = torch.log1p(-a).double()
    cs = torch.cumsum(la, 0)
    incl = cs - torch.index_select(cs - la, 0, segs.start)  # log of the transmittance after each entry
    return (a > 0) & (incl >= math.log(MIN_T))


def _chunks(b: Binning, q_tile: Tensor, chunk_tiles: int | None) -> list[tuple[int, int]]:
    """Pair ranges ``[(p0, p1)]`` of consecutive camera-tiles."""
    n_ct = b.offsets.numel() - 1
    if chunk_tiles is not None:
        bounds = torch.arange(0, n_ct, max(1, int(chunk_tiles)), device=b.offsets.device)
    else:
        cum = torch.cumsum(q_tile, 0) - q_tile
        cid = torch.div(cum, PAIR_PIXEL_BUDGET, rounding_mode="floor")
        bounds = torch.nonzero(torch.diff(cid, prepend=cid[:1] - 1)).flatten()
    edges = b.offsets[torch.cat([bounds, bounds.new_tensor([n_ct])])].tolist()
    return [(p0, p1) for p0, p1 in itertools.pairwise(edges) if p1 > p0]


def _pair_boxes(b: Binning, eff: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Pixel box of every pair: effective rectangle clipped to the pair's tile. ``[P]`` x0, y0 and size."""
    tloc = b.ctile % (b.TX * b.TY)
    tx0 = (tloc % b.TX) * b.tile
    ty0 = torch.div(tloc, b.TX, rounding_mode="floor") * b.tile
    e = eff[b.splat]
    x0 = torch.maximum(e[:, 0], tx0)
    x1 = torch.minimum(torch.minimum(e[:, 1], tx0 + b.tile - 1), torch.full_like(tx0, b.W - 1))
    y0 = torch.maximum(e[:, 2], ty0)
    y1 = torch.minimum(torch.minimum(e[:, 3], ty0 + b.tile - 1), torch.full_like(ty0, b.H - 1))
    nx, ny = (x1 - x0 + 1).clamp_min(0), (y1 - y0 + 1).clamp_min(0)
    return torch.stack([x0, y0], -1), nx, ny


def _take(x: Tensor, idx: Tensor) -> Tensor:
    """``x[idx]`` along dim 0 (``index_select`` is much faster than advanced indexing on CPU)."""
    return torch.index_select(x, 0, idx)


def _expand(b: Binning, p0: int, p1: int, xy0: Tensor, nx: Tensor, ny: Tensor, alpha_fn, dtype):
    """Pair-pixels of pairs ``[p0, p1)`` that pass the alpha skip, grouped by pixel.

    Entries are generated pair by pair (so in depth order within each tile), their alpha is evaluated
    without gradient and those below 1/255 dropped; a stable sort by the chunk-local pixel id then
    groups them by pixel and keeps the depth order.
    Returns: splat ``[Q]``, pixel centres ``[Q, 2]``, raw alpha ``[Q]``, Segments.
    """
    dev = xy0.device
    nx, ny, xy0 = nx[p0:p1], ny[p0:p1], xy0[p0:p1]
    count = nx * ny
    pair = torch.repeat_interleave(torch.arange(p1 - p0, device=dev, dtype=torch.int32), count)
    k = (torch.arange(pair.numel(), device=dev) - _take(torch.cumsum(count, 0) - count, pair)).int()
    nxp = _take(nx.int(), pair)
    row = torch.div(k, nxp, rounding_mode="floor")
    col = k - row * nxp
    xyp = torch.stack([_take(xy0[:, 0].int(), pair) + col, _take(xy0[:, 1].int(), pair) + row], -1)
    splat = _take(b.splat[p0:p1], pair)
    xyf = xyp.to(dtype) + 0.5
    with torch.no_grad():
        alpha = alpha_fn(splat, xyf)
    idx = torch.nonzero(alpha >= MIN_ALPHA).flatten()
    cam = torch.div(b.ctile[p0:p1], b.TX * b.TY, rounding_mode="floor")
    base = (cam * b.H + xy0[:, 1]) * b.W + xy0[:, 0]  # [P] flat pixel id of each pair box's corner
    base0 = int(base.min())
    local = _take((base - base0).int(), pair) + row * b.W + col
    local, perm = torch.sort(_take(local, idx), stable=True)
    perm = _take(idx, perm)
    upix, counts = torch.unique_consecutive(local, return_counts=True)
    seg = torch.repeat_interleave(torch.arange(upix.numel(), device=dev), counts)
    start = _take(torch.cumsum(counts, 0) - counts, seg)
    segs = Segments(seg, start, upix.numel(), upix.long() + base0)
    return _take(splat, perm), _take(xyf, perm), _take(alpha, perm), segs


Shade = Callable[[Tensor, Tensor, Segments], Tensor]
AlphaFn = Callable[[Tensor, Tensor], Tensor]


def rasterize(b: Binning, eff: Tensor, alpha_fn: AlphaFn, shade: Shade, K: int, dtype: torch.dtype,
              chunk_tiles: int | None = None) -> Tensor:
    """Run ``shade`` on every chunk of tiles and assemble the per-pixel results.

    Args:
        b: the sorted pairs; eff: ``[C*N, 4]`` long inclusive pixel box ``(x0, x1, y0, y1)`` that contains
            every pixel where the splat's alpha can reach 1/255 (empty when ``x1 < x0``).
        alpha_fn: ``(splat [Q], xy [Q, 2] pixel centres) -> [Q]`` raw alpha (called without gradient to
            find the entries that are composited: the rest is dropped before ``shade``, which is exact).
        shade: ``(splat [Q], xy [Q, 2], segs) -> [segs.n, K]`` per-pixel values of a chunk; it receives only
            the composited entries, so it may use :func:`composite_kept`.
        chunk_tiles: camera-tiles per chunk; None = automatic (bounded pair-pixels per chunk).
    Returns:
        ``[C*H*W, K]`` per-pixel values (0 where no splat reaches).
    """
    pixels, values = [], []
    for splat, xy, _, segs in _composited(b, eff, alpha_fn, dtype, chunk_tiles):
        values.append(shade(splat, xy, segs))
        pixels.append(segs.pixel)
    out = torch.zeros(b.C * b.H * b.W, K, dtype=dtype, device=eff.device)
    if not pixels:
        return out
    return out.index_put((torch.cat(pixels),), torch.cat(values))


def _composited(b: Binning, eff: Tensor, alpha_fn: AlphaFn, dtype: torch.dtype, chunk_tiles: int | None):
    """Each chunk's composited entries: ``(splat [Q], xy [Q, 2], alpha [Q] (no gradient), segs)``."""
    xy0, nx, ny = _pair_boxes(b, eff)
    q_tile = torch.zeros(b.offsets.numel() - 1, dtype=torch.long, device=xy0.device)
    q_tile.index_add_(0, b.ctile, nx * ny)
    for p0, p1 in _chunks(b, q_tile, chunk_tiles):
        splat, xy, alpha, segs = _expand(b, p0, p1, xy0, nx, ny, alpha_fn, dtype)
        keep = composited_mask(alpha, segs)
        if not bool(keep.any()):
            continue
        idx = torch.nonzero(keep).flatten()
        yield _take(splat, idx), _take(xy, idx), _take(alpha, idx), segs.select(keep, idx)


@torch.no_grad()
def composite_weights(b: Binning, eff: Tensor, alpha_fn: AlphaFn, dtype: torch.dtype,
                      chunk_tiles: int | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """The weights ``w = alpha T`` with which :func:`rasterize` composites: ``pixel [Q]`` (flat ``c*H*W + y*W + x``),
    ``entry [Q]`` (long) and ``w [Q]`` of every composited (pixel, entry), the pixels' entries in depth order."""
    pix, ent, ws = [], [], []
    for splat, _, alpha, segs in _composited(b, eff, alpha_fn, dtype, chunk_tiles):
        w, _ = composite_kept(alpha, segs)
        pix.append(torch.index_select(segs.pixel, 0, segs.seg))
        ent.append(splat)
        ws.append(w)
    if not pix:
        empty = eff.new_zeros(0, dtype=torch.long)
        return empty, empty, torch.zeros(0, dtype=dtype, device=eff.device)
    return torch.cat(pix), torch.cat(ent), torch.cat(ws)


def weights_record(b: Binning, eff: Tensor, alpha_fn: AlphaFn, dtype: torch.dtype, alpha: Tensor,
                   chunk_tiles: int | None = None):
    """:func:`composite_weights` in the layout of the fused kernels' record
    (:func:`arcsem.backbones.gaussians.fused.composite_weights`): CSR over the pixels (here the columns are the
    ``M = C*N`` entries themselves: ``ids = arange(M)``), ``t_final = 1 - alpha`` (``alpha [C, H, W, 1]``, the
    render's), ``transpose`` (a transposed CSR copy: sparse products on any device) and ``nbytes``."""
    import warnings
    from types import SimpleNamespace

    pix, ent, w = composite_weights(b, eff, alpha_fn, dtype, chunk_tiles)
    P, M = b.C * b.H * b.W, eff.shape[0]
    with warnings.catch_warnings():  # PyTorch's notice that sparse CSR support is in beta
        warnings.simplefilter("ignore", UserWarning)
        W = torch.sparse_coo_tensor(torch.stack([pix, ent]), w, (P, M)).coalesce().to_sparse_csr()
        Wt = torch.sparse_coo_tensor(torch.stack([ent, pix]), w, (M, P)).coalesce().to_sparse_csr()
        i32 = lambda t: t.to(torch.int32)
        Wt = torch.sparse_csr_tensor(i32(Wt.crow_indices()), i32(Wt.col_indices()), Wt.values(), Wt.shape)
    pix_ptr, pix_pair = i32(W.crow_indices()), i32(W.col_indices())
    held = (pix_ptr, pix_pair, W.values(), Wt.crow_indices(), Wt.col_indices(), Wt.values())
    return SimpleNamespace(pix_ptr=pix_ptr, pix_pair=pix_pair, pix_w=W.values(), t_final=(1 - alpha.detach()).reshape(-1),
                           ids=torch.arange(M, device=eff.device), transpose=lambda g: Wt @ g,
                           nbytes=sum(t.numel() * t.element_size() for t in held))


def screen_position_leaf(centre2d: Tensor) -> tuple[Tensor, Tensor]:
    """A leaf ``means2d [C, N, 2]`` (value: the projected centres) and ``shift = means2d - value`` (zero),
    so that after backward ``means2d.grad`` is the loss gradient w.r.t. each splat's screen position
    (what densification thresholds, like the official ``viewspace_points``). No-op without grad."""
    means2d = centre2d.detach().clone()
    if not torch.is_grad_enabled():
        return means2d, torch.zeros_like(means2d)
    means2d.requires_grad_(True)
    return means2d, means2d - centre2d.detach()
