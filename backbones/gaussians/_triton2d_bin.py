"""``rasterizer=triton``: the tile binning's expansion of splats to (camera-tile, splat) pairs as one Triton kernel.

:func:`.raster.bin_tiles` (the reference) expands each splat's tile rectangle to pairs with ~30 PyTorch operators
(``repeat_interleave``, index arithmetic, gathers); here one lane a splat writes its pairs' sort keys
``(camera-tile << 32) | depth rank`` and splat indices from its exclusive prefix of pair counts. The depth ranks, the
prefix sum, the sort and the offsets stay PyTorch's (one operator each); the total pair count is the one host read
of a training step, as before. Equal pairs, order and offsets (tests/test_triton2d.py). Imported on first use.
"""
from __future__ import annotations

import functools

import torch
import triton
import triton.language as tl
from torch import Tensor

from .raster import Binning

__all__ = ["bin_tiles_triton"]

BLOCK = 128  # splats a program


@triton.jit(do_not_specialize=["M", "N"])  # the splat counts change at each densification
def _expand(rects, rank, ends, key, splat, M, N, TX, TY, BLOCK: tl.constexpr):
    """Splat ``s``'s pairs at ``[ends[s] - count, ends[s])``: keys and the splat index, rectangle row by row."""
    s = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = s < M
    x0 = tl.load(rects + 4 * s, mask=m, other=0)
    x1 = tl.load(rects + 4 * s + 1, mask=m, other=0)
    y0 = tl.load(rects + 4 * s + 2, mask=m, other=0)
    y1 = tl.load(rects + 4 * s + 3, mask=m, other=0)
    nx = tl.maximum(x1 - x0, 0)
    count = nx * tl.maximum(y1 - y0, 0)
    start = tl.load(ends + s, mask=m, other=0) - count
    low = tl.load(rank + s, mask=m, other=0)
    cam = s // N
    top = tl.max(count, axis=0)
    for j in range(top):
        on = m & (j < count)
        div = tl.maximum(nx, 1)
        ctile = cam.to(tl.int64) * (TX * TY) + (y0 + j // div) * TX + (x0 + j % div)
        tl.store(key + start + j, (ctile << 32) | low, mask=on)
        tl.store(splat + start + j, s.to(tl.int64), mask=on)


@torch.no_grad()
def bin_tiles_triton(rects: Tensor, depth: Tensor, W: int, H: int, tile: int) -> Binning:
    """:func:`.raster.bin_tiles` with the expansion on the Triton kernel: ``rects [C, N, 4]`` long tile rectangles,
    ``depth [C, N]`` the sort key (ties keep the splat order) -> the sorted pairs."""
    C, N = depth.shape
    M, dev = C * N, depth.device
    TX, TY = -(-W // tile), -(-H // tile)
    rank = torch.empty(C, N, dtype=torch.long, device=dev)
    rank.scatter_(1, torch.argsort(depth, dim=1, stable=True), _aranges(N, dev).expand(C, N))
    rects = rects.reshape(M, 4).contiguous()
    sizes = (rects[:, 1::2] - rects[:, 0::2]).clamp_min(0)  # [M, 2] tiles along x and y
    ends = torch.cumsum(sizes.prod(1), 0)
    P = int(ends[-1]) if M else 0  # the step's one host read: the pair list's length
    key = torch.empty(P, dtype=torch.long, device=dev)
    splat = torch.empty(P, dtype=torch.long, device=dev)
    if M:
        _expand[(triton.cdiv(M, BLOCK),)](rects, rank, ends, key, splat, M, N, TX, TY, BLOCK=BLOCK, num_warps=4)
    key, perm = torch.sort(key)
    ctile = key >> 32
    offsets = torch.searchsorted(ctile, _aranges(C * TX * TY + 1, dev))
    return Binning(splat[perm], ctile, offsets, C, H, W, tile, TX, TY)


@functools.lru_cache(maxsize=16)
def _aranges(n: int, dev: torch.device) -> Tensor:
    """``arange(n)`` on ``dev``, made once per size and device (read-only)."""
    return torch.arange(n, device=dev)
