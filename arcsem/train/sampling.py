"""What each training step sees: whole views (image backbones) or random rays (ray backbones).

Both samplers draw from their own ``torch.Generator`` and expose ``state_dict`` /
``load_state_dict``, so a resumed run draws exactly the batches an uninterrupted one would.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..plugins import Batch
from ..scene import Split

__all__ = ["RaySampler", "ViewSampler", "make_sampler", "resize_scene", "resize_split"]


def _rows(t, idx: list[int]):
    """Rows ``idx`` of a tensor or :class:`~arcsem.cameras.Cameras` without an index tensor (which a GPU would have
    to receive from the host, a synchronisation): one row is a view, several a concatenation of views."""
    if len(idx) == 1:
        return t[idx[0]:idx[0] + 1]
    parts = [t[i:i + 1] for i in idx]
    return type(t).cat(parts) if hasattr(type(t), "cat") else torch.cat(parts)


class ViewSampler:
    """``batch_views`` views per step, a fresh random permutation of all views every epoch.

    The split's images, masks and cameras are moved to ``device`` once; a step takes its views there by slicing
    (the order is drawn on the host from the sampler's own generator, so it is the same on every device)."""

    def __init__(self, split: Split, batch_views: int = 1, seed: int = 0, device: str | torch.device = "cpu"):
        if len(split) == 0:
            raise ValueError("cannot train on a split without views")
        self.split, self.batch_views, self.device = split, min(batch_views, len(split)), torch.device(device)
        self.gen = torch.Generator().manual_seed(seed)
        self.order: list[int] = []
        dev = self.device
        self.cameras, self.images = split.cameras.to(dev), split.images.to(dev)
        self.masks = None if split.masks is None else split.masks.to(dev, split.images.dtype)[..., None]  # [N,H,W,1]
        self.ids = torch.arange(len(split), device=dev)

    def next(self) -> Batch:
        if len(self.order) < self.batch_views:
            self.order += torch.randperm(len(self.split), generator=self.gen).tolist()
        idx, self.order = self.order[: self.batch_views], self.order[self.batch_views:]
        return Batch(cameras=_rows(self.cameras, idx), images=_rows(self.images, idx), indices=_rows(self.ids, idx),
                     masks=None if self.masks is None else _rows(self.masks, idx), views=tuple(idx))

    def state_dict(self) -> dict:
        return {"gen": self.gen.get_state(), "order": list(self.order)}

    def load_state_dict(self, state: dict) -> None:
        self.gen.set_state(state["gen"].cpu())  # a CPU generator, whatever map_location did
        self.order = list(state["order"])


class RaySampler:
    """``rays_per_batch`` rays drawn uniformly (with replacement) from every pixel of every view.

    Rays are generated per batch through :meth:`Cameras.rays` (one camera per sampled ray), so memory
    stays at the images themselves even at full resolution (no ``[N*H*W, 3]`` ray tables).
    """

    def __init__(self, split: Split, rays_per_batch: int = 5000, seed: int = 0, device: str | torch.device = "cpu"):
        if len(split) == 0:
            raise ValueError("cannot train on a split without views")
        self.split, self.R, self.device = split, rays_per_batch, torch.device(device)
        self.gen = torch.Generator().manual_seed(seed)
        self.h, self.w = split.images.shape[1:3]
        self.colors = split.images.reshape(-1, 3)
        self.masks = None if split.masks is None else split.masks.reshape(-1, 1)

    def next(self) -> Batch:
        k = torch.randint(0, self.colors.shape[0], (self.R,), generator=self.gen)
        view, pix = k // (self.h * self.w), k % (self.h * self.w)
        uv = torch.stack([pix % self.w, pix // self.w], -1).to(self.split.cameras.K.dtype) + 0.5
        cams = self.split.cameras[view]
        o, d = cams.rays(uv[:, None, :])  # [R, 1, 3]
        dev = self.device
        masks = None if self.masks is None else self.masks[k].to(self.colors.dtype).to(dev)
        return Batch(cameras=self.split.cameras.to(dev), images=self.colors[k].to(dev), indices=view.to(dev),
                     masks=masks, rays_o=o[:, 0].to(dev), rays_d=d[:, 0].to(dev),
                     ray_image_ids=cams.image_ids.to(dev))

    def state_dict(self) -> dict:
        return {"gen": self.gen.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.gen.set_state(state["gen"].cpu())  # a CPU generator, whatever map_location did


def make_sampler(split: Split, batch_mode: str, batch_views: int = 1, rays_per_batch: int = 5000, seed: int = 0,
                 device: str | torch.device = "cpu") -> ViewSampler | RaySampler:
    """The sampler for a backbone's ``batch_mode`` (``"image"`` or ``"rays"``)."""
    if batch_mode == "rays":
        return RaySampler(split, rays_per_batch, seed, device)
    return ViewSampler(split, batch_views, seed, device)


def _resize(x: Tensor | None, h: int, w: int, mode: str) -> Tensor | None:
    """``[N,H,W(,ch)]`` -> ``[N,h,w(,ch)]``: ``area`` for images, ``nearest`` for masks and depths."""
    if x is None:
        return None
    squeeze = x.ndim == 3
    y = (x[..., None] if squeeze else x).permute(0, 3, 1, 2)
    dtype = y.dtype
    y = F.interpolate(y.float(), size=(h, w), mode=mode)
    y = y.permute(0, 2, 3, 1)
    y = y[..., 0] if squeeze else y
    return (y > 0.5) if dtype == torch.bool else y.to(dtype)


def resize_split(split: Split, downscale: float = 1.0, width: int | None = None) -> Split:
    """The split at a lower resolution: by ``downscale`` (2 = half size) or to ``width`` pixels; never
    larger than it is (a ``width`` above the images' keeps their size).

    Images and colours are box-filtered (``area``); masks, depths and normals take the nearest
    sample (no mixing of foreground and background depths). Cameras follow via ``Cameras.scaled``.
    """
    factor = min((width / split.cameras.width) if width else 1.0 / float(downscale), 1.0)
    if abs(factor - 1.0) < 1e-9 or len(split) == 0:
        return split
    cams = split.cameras.scaled(factor)
    h, w = cams.height, cams.width
    area = lambda t: _resize(t, h, w, "area")
    near = lambda t: _resize(t, h, w, "nearest")
    from dataclasses import replace

    return replace(split, cameras=cams, images=area(split.images), masks=near(split.masks), depths=near(split.depths),
                   normals=near(split.normals), colors=area(split.colors), clean=area(split.clean))


def resize_scene(scene, downscale: float = 1.0, width: int | None = None):
    """``scene`` with both splits at the resolution of :func:`resize_split` (stage 1 and stage 2 train there)."""
    from dataclasses import replace

    return replace(scene, train=resize_split(scene.train, downscale, width), test=resize_split(scene.test, downscale, width))
