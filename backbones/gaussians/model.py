"""The Gaussian parameter container shared by 2DGS and 3DGS.

Raw (optimised) parameters and their activations, as in the official 3DGS/2DGS code:

================  =====================  ==========================================
parameter         shape                  activation
================  =====================  ==========================================
``means``         ``[N, 3]``             none (world position)
``quats``         ``[N, 4]`` (w,x,y,z)   normalised by the rasteriser / :attr:`rotations`
``log_scales``    ``[N, S]`` S = 2 or 3  ``exp``
``opacity_logits````[N]``                ``sigmoid``
``sh_dc``         ``[N, 1, 3]``          colour = ``max(SH . basis + 0.5, 0)``
``sh_rest``       ``[N, K-1, 3]``        (K = (sh_degree + 1)^2)
================  =====================  ==========================================

``active_sh_degree`` is a buffer (saved in checkpoints; set it with ``set_active_sh_degree``); it grows by one every
``sh_increase_every`` steps in stage 1 (:func:`active_sh_degree_at`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor, nn

from arcsem.cameras import Cameras
from arcsem.rotations import quat_to_rotmat

from ..sh import eval_sh, num_sh_coeffs

if TYPE_CHECKING:
    from arcsem.act import ACT

__all__ = ["PARAM_NAMES", "GaussianModel", "active_sh_degree_at"]

PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


def active_sh_degree_at(step: int, max_degree: int, every: int = 1000) -> int:
    """SH degree in use at ``step``: ``min(max_degree, step // every)`` (official: +1 every 1000)."""
    return min(max_degree, max(0, step) // every)


class GaussianModel(nn.Module):
    """``N`` Gaussians with SH colours up to ``sh_degree``."""

    def __init__(self, params: dict[str, Tensor], sh_degree: int = 3):
        super().__init__()
        self.sh_degree = sh_degree
        n = params["means"].shape[0]
        k = num_sh_coeffs(sh_degree)
        expected = {"means": (n, 3), "quats": (n, 4), "opacity_logits": (n,), "sh_dc": (n, 1, 3),
                    "sh_rest": (n, k - 1, 3)}
        for name in PARAM_NAMES:
            t = params[name]
            if name in expected and tuple(t.shape) != expected[name]:
                raise ValueError(f"GaussianModel: '{name}' has shape {tuple(t.shape)}, expected {expected[name]}")
            setattr(self, name, nn.Parameter(t.detach().clone().float().contiguous()))
        if self.log_scales.shape[0] != n or self.log_scales.shape[1] not in (2, 3):
            raise ValueError(f"GaussianModel: 'log_scales' has shape {tuple(self.log_scales.shape)}, expected [{n}, 2|3]")
        self.register_buffer("active_sh_degree", torch.zeros((), dtype=torch.long))
        self._sh_active = 0  # host copy of the buffer: colors() reads it without waiting for a device

    def set_active_sh_degree(self, degree: int) -> None:
        """Set :attr:`active_sh_degree` (the buffer and its host copy; the buffer is written only on a change)."""
        if degree != self._sh_active:
            self.active_sh_degree.fill_(degree)
            self._sh_active = int(degree)

    # ------------------------------------------------------------------ activations
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def scales(self) -> Tensor:
        """``[N, S]`` world-space scales."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> Tensor:
        """``[N]`` in (0, 1)."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> Tensor:
        """``[N, 3, 3]`` rotation matrices (columns: local axes in world)."""
        return quat_to_rotmat(self.quats)

    @property
    def sh(self) -> Tensor:
        """``[N, K, 3]`` all SH coefficients."""
        return torch.cat([self.sh_dc, self.sh_rest], 1)

    def params(self) -> dict[str, nn.Parameter]:
        return {name: getattr(self, name) for name in PARAM_NAMES}

    def view_dirs(self, cams: Cameras) -> Tensor:
        """``[C, N, 3]`` world viewing directions: means - camera centre (pinhole) or camera forward (ortho)."""
        if cams.is_ortho:
            return cams.forward[:, None, :].to(self.means.dtype).expand(len(cams), len(self), 3)
        return self.means[None] - cams.centers[:, None, :].to(self.means.dtype)

    def colors(self, cams: Cameras, degree: int | None = None, impl: str = "torch", act: ACT | None = None) -> Tensor:
        """``[C, N, 3]`` colours seen by each camera: ``max(SH(view dir) + 0.5, 0)``, then ``act`` by the cameras'
        image ids if given (:meth:`ACT.apply`).

        ``degree`` defaults to :attr:`active_sh_degree`; ``impl``: ``torch`` (:func:`eval_sh` and :meth:`ACT.apply`,
        the reference), ``cpp`` (one fused kernel, :func:`arcsem.backbones.gaussians.fused.sh_colors`; CPU tensors)
        or ``triton`` (two Triton kernels, :mod:`._triton_sh`; CUDA tensors).
        """
        deg = self._sh_active if degree is None else degree
        deg = min(deg, self.sh_degree)
        if impl in ("cpp", "triton"):
            if impl == "cpp":
                from .fused import sh_colors
            else:
                from ._triton_sh import sh_colors_triton as sh_colors

            origins = cams.forward if cams.is_ortho else cams.centers
            affine = None if act is None else act.transforms(torch.as_tensor(cams.image_ids))
            return sh_colors(self.means, self.sh_dc, self.sh_rest, origins, cams.is_ortho, deg, act=affine)
        sh = self.sh if deg > 0 else self.sh_dc
        rgb = torch.clamp_min(eval_sh(deg, sh[None], self.view_dirs(cams)) + 0.5, 0.0)
        return rgb if act is None else act.apply(rgb, cams.image_ids)

    # ------------------------------------------------------------------ resizing
    def set_params(self, values: dict[str, Tensor]) -> None:
        """Replace the data of every parameter in place (keeps Parameter identity for optimisers).

        Gradients are dropped (their shape may no longer match), like the official code's new
        Parameters after densification.
        """
        for name, v in values.items():
            p = getattr(self, name)
            p.data = v.detach().to(dtype=p.dtype, device=p.device).contiguous()
            p.grad = None

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # A checkpoint may hold a different number of Gaussians: resize before copying.
        for name in PARAM_NAMES:
            key = prefix + name
            p = getattr(self, name)
            if key in state_dict and state_dict[key].shape != p.shape:
                p.data = torch.empty(state_dict[key].shape, dtype=p.dtype, device=p.device)
                p.grad = None
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._sh_active = int(self.active_sh_degree)  # the host copy: one read, when a checkpoint is loaded
