"""Random splat scenes and cameras for the rasteriser tests and benchmarks (not used in training)."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from arcsem.cameras import Cameras, look_at

__all__ = ["Splats", "orbit_cameras", "random_splats"]


@dataclass
class Splats:
    """Raw splat parameters: means ``[N, 3]``, quats ``[N, 4]``, scales ``[N, 3]``, opacities ``[N]``,
    colors ``[C, N, 3]``."""

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    colors: Tensor

    def params(self, dims: int = 3) -> list[Tensor]:
        """``[means, quats, scales[:, :dims], opacities, colors]`` as fresh leaves requiring grad."""
        ps = [self.means, self.quats, self.scales[:, :dims], self.opacities, self.colors]
        return [p.detach().clone().requires_grad_(True) for p in ps]


def random_splats(N: int, C: int = 1, *, scale: tuple[float, float] = (0.03, 0.18), extent: float = 1.0,
                  opacity: tuple[float, float] = (0.05, 0.95), seed: int = 0,
                  dtype: torch.dtype = torch.float64) -> Splats:
    """``N`` random splats in the box ``[-extent/2, extent/2]^3`` with log-uniform scales."""
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g, dtype=dtype)
    lo, hi = torch.log(torch.tensor(scale, dtype=dtype))
    return Splats(
        means=(r(N, 3) - 0.5) * extent,
        quats=torch.randn(N, 4, generator=g, dtype=dtype),
        scales=torch.exp(lo + (hi - lo) * r(N, 3)),
        opacities=opacity[0] + (opacity[1] - opacity[0]) * r(N),
        colors=r(C, N, 3),
    )


def orbit_cameras(C: int, W: int, H: int, *, distance: float = 3.0, focal: float | None = None,
                  ortho: bool = False, dtype: torch.dtype = torch.float64) -> Cameras:
    """``C`` cameras at ``distance`` around the origin looking at it; ``focal`` in pixels (pinhole) so the
    unit box fills most of the image; orthographic cameras get the same magnification at the origin."""
    ang = torch.linspace(0, 1.2, C, dtype=dtype) if C > 1 else torch.zeros(1, dtype=dtype)
    eye = torch.stack([distance * torch.sin(ang) + 0.1, -0.15 + 0.3 * ang, -distance * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros(C, 3, dtype=dtype), torch.tensor([0.0, -1.0, 0.0], dtype=dtype))
    f = focal if focal is not None else 0.9 * W * distance / 1.5
    if ortho:
        f = f / distance
    K = torch.tensor([[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]], dtype=dtype).repeat(C, 1, 1)
    return Cameras(w2c, K, W, H, "orthographic" if ortho else "pinhole")
