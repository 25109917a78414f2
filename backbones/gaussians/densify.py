"""Adaptive density control (Kerbl et al. 2023): statistics, clone, split, prune, opacity reset.

Every structural change is one *row map*: new rows are ``values`` with ``src [N']`` (the old row each
new row comes from) and ``fresh [N']`` (rows that are new primitives). :func:`remap_optimizers`
applies the same map to every per-row optimiser state tensor (Adam ``exp_avg``/``exp_avg_sq``,
SGD momentum, ...): surviving rows keep their state, fresh rows (clones, split children) start at
zero, pruned rows disappear -- exactly what the official code does with its tensor surgery.
Parameters keep their identity (``p.data`` is replaced), so optimisers and trainers holding
references stay valid.

Densification statistic (documented choice): our rasteriser is a pure function of the 3-D means,
so there is no screen-space ``means2D`` tensor to read a gradient from. We instead project the 3-D
mean gradient onto each camera's image plane and convert it to the official NDC units:
``dL/du_pix = dL/dX_cam,x * z / fx`` (pinhole; ``1 / fx`` orthographic), likewise for ``v`` with
``fy``, and ``dL/du_ndc = dL/du_pix * W / 2``, ``dL/dv_ndc = dL/dv_pix * H / 2``. Its norm is
accumulated for every camera in which the splat is visible and averaged over those times. For a
batch of one camera (the official setting) this equals the official statistic up to the parts of
the gradient that reach the mean through its depth; with several cameras in a batch the summed
3-D gradient is projected into each of them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.rotations import quat_to_rotmat

from .model import GaussianModel

__all__ = [
    "DensifyStats",
    "clone_split_prune",
    "remap_optimizers",
    "reset_opacity",
    "screen_grad_norms",
]


@dataclass
class DensifyStats:
    """Per-Gaussian accumulators: ``grad_sum [N]``, ``count [N]``, ``max_radii [N]`` (pixels)."""

    grad_sum: Tensor
    count: Tensor
    max_radii: Tensor

    @staticmethod
    def zeros(n: int, device=None) -> DensifyStats:
        z = torch.zeros(n, device=device)
        return DensifyStats(z, z.clone(), z.clone())

    def __len__(self) -> int:
        return self.grad_sum.shape[0]

    def mean_grad(self) -> Tensor:
        """``[N]`` average NDC gradient norm over the times visible (0 if never visible)."""
        return torch.where(self.count > 0, self.grad_sum / self.count.clamp_min(1), torch.zeros_like(self.grad_sum))

    def accumulate(self, norms: Tensor, visible: Tensor, radii: Tensor) -> None:
        """Add ``norms [C, N]`` where ``visible [C, N]``; track the largest ``radii [C, N]`` seen. The accumulators
        follow the model to its device (they are made before the model is moved there)."""
        if self.grad_sum.device != norms.device:
            self.grad_sum, self.count, self.max_radii = (t.to(norms.device)
                                                         for t in (self.grad_sum, self.count, self.max_radii))
        vis = visible.to(norms.dtype)
        self.grad_sum += (norms * vis).sum(0).to(self.grad_sum)
        self.count += vis.sum(0).to(self.count)
        r = torch.where(visible, radii.to(self.max_radii.dtype), torch.zeros_like(radii, dtype=self.max_radii.dtype))
        self.max_radii = torch.maximum(self.max_radii, r.max(0).values)


def screen_grad_norms(grad_means: Tensor, means: Tensor, cams: Cameras) -> Tensor:
    """``[C, N]`` norm of the image-plane NDC gradient (see module docstring).

    Args:
        grad_means: ``[N, 3]`` dL/d(world mean). means: ``[N, 3]``.
    """
    g = grad_means.detach()
    R = cams.world_to_cam[:, :3, :3].to(g.dtype)
    g_cam = torch.einsum("cij,nj->cni", R, g)  # [C, N, 3]
    fx, fy = cams.K[:, 0, 0].to(g.dtype)[:, None], cams.K[:, 1, 1].to(g.dtype)[:, None]
    if cams.is_ortho:
        du, dv = 1.0 / fx, 1.0 / fy
    else:
        z = cams.to_camera(means.detach().to(cams.world_to_cam.dtype))[..., 2].to(g.dtype)
        du, dv = z / fx, z / fy
    gu = g_cam[..., 0] * du * (cams.width / 2)
    gv = g_cam[..., 1] * dv * (cams.height / 2)
    return torch.sqrt(gu * gu + gv * gv)


def remap_optimizers(params: dict[str, Tensor], src: Tensor, fresh: Tensor, optimizers) -> None:
    """Apply the row map to optimiser state of every parameter in ``params`` (before resizing them).

    Args:
        params: name -> Parameter (old size ``N``).
        src: ``[N']`` long, old row of each new row. fresh: ``[N']`` bool, rows whose state is zeroed.
        optimizers: dict (or list) of torch optimisers; parameters they do not hold are ignored.
    """
    opts = optimizers.values() if isinstance(optimizers, dict) else optimizers
    for p in params.values():
        n = p.shape[0]
        for opt in opts:
            state = opt.state.get(p)
            if not state:
                continue
            for key, v in list(state.items()):
                if torch.is_tensor(v) and v.ndim >= 1 and v.shape[0] == n and v.shape == p.shape:
                    new = v[src.to(v.device)]
                    new[fresh.to(v.device)] = 0
                    state[key] = new


def _apply(model: GaussianModel, values: dict[str, Tensor], src: Tensor, fresh: Tensor, optimizers) -> None:
    remap_optimizers(model.params(), src, fresh, optimizers)
    model.set_params(values)


def _split_children(p: dict[str, Tensor], idx: Tensor, n: int, generator) -> dict[str, Tensor]:
    """``n`` children per Gaussian ``idx``: positions sampled from the parent, scales / (0.8 n)."""
    scales = torch.exp(p["log_scales"][idx]).repeat_interleave(n, 0)  # [M n, S]
    if scales.shape[1] == 2:  # surfel: no extent along the normal
        scales = torch.cat([scales, torch.zeros_like(scales[:, :1])], 1)
    noise = torch.randn(scales.shape, generator=generator, dtype=scales.dtype).to(scales.device)
    R = quat_to_rotmat(p["quats"][idx]).repeat_interleave(n, 0)
    out = {k: v[idx].repeat_interleave(n, 0) for k, v in p.items()}
    out["means"] = out["means"] + (R @ (noise * scales)[..., None])[..., 0]
    out["log_scales"] = out["log_scales"] - math.log(0.8 * n)
    return out


def clone_split_prune(
    model: GaussianModel,
    stats: DensifyStats,
    optimizers,
    *,
    grad_threshold: float,
    percent_dense: float,
    extent: float,
    min_opacity: float,
    max_screen_size: float | None = None,
    max_world_scale: float = 0.1,
    n_split: int = 2,
    generator: torch.Generator | None = None,
) -> dict[str, int]:
    """One densify-and-prune pass of the official schedule, as one row map.

    Clone Gaussians with mean gradient ``>= grad_threshold`` and max scale ``<= percent_dense *
    extent``; split the larger ones into ``n_split`` children; then prune opacity ``< min_opacity``
    and, if ``max_screen_size`` is set, screen radius ``> max_screen_size`` px or max world scale
    ``> max_world_scale * extent``. (The official code zeroes the screen radii before testing them,
    so its screen-size test never fires; we apply it as described.) Returns counts per operation.
    """
    p = {k: v.detach() for k, v in model.params().items()}
    n = len(model)
    big_grad = stats.mean_grad().to(p["means"].device) >= grad_threshold
    max_scale = torch.exp(p["log_scales"]).max(1).values
    clone = big_grad & (max_scale <= percent_dense * extent)
    split = big_grad & ~clone
    rows = torch.arange(n, device=p["means"].device)
    keep_idx, clone_idx, split_idx = rows[~split], rows[clone], rows[split]
    children = _split_children(p, split_idx, n_split, generator)
    values = {k: torch.cat([v[keep_idx], v[clone_idx], children[k]]) for k, v in p.items()}
    src = torch.cat([keep_idx, clone_idx, split_idx.repeat_interleave(n_split)])
    fresh = torch.cat([torch.zeros_like(keep_idx, dtype=torch.bool),
                       torch.ones(len(clone_idx) + len(children["means"]), dtype=torch.bool, device=rows.device)])
    prune = torch.sigmoid(values["opacity_logits"]) < min_opacity
    if max_screen_size is not None:
        big_screen = (stats.max_radii.to(rows.device) > max_screen_size)[src] & ~fresh
        big_world = torch.exp(values["log_scales"]).max(1).values > max_world_scale * extent
        prune = prune | big_screen | big_world
    if prune.all():  # never leave an empty model behind
        prune = torch.zeros_like(prune)
    keep = ~prune
    values = {k: v[keep] for k, v in values.items()}
    _apply(model, values, src[keep], fresh[keep], optimizers)
    return {"cloned": len(clone_idx), "split": len(split_idx), "pruned": int(prune.sum()), "total": len(model)}


def reset_opacity(model: GaussianModel, optimizers, max_opacity: float = 0.01) -> None:
    """Set opacities to ``min(o, max_opacity)`` and zero their optimiser state (official behaviour)."""
    o = torch.clamp_max(model.opacities.detach(), max_opacity)
    logits = torch.log(o) - torch.log1p(-o)
    n = len(model)
    rows = torch.arange(n, device=o.device)
    remap_optimizers({"opacity_logits": model.opacity_logits}, rows, torch.ones(n, dtype=torch.bool), optimizers)
    model.set_params({"opacity_logits": logits})
