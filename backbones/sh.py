"""Real spherical harmonics up to degree 3, in the basis and sign convention of the 3DGS/2DGS code.

Basis functions are indexed ``k = l*l + l + m`` (``m = -l..l``) and equal the orthonormal real SH
built from the complex ``Y_l^m`` *with* the Condon-Shortley phase:
``Y_{l,m} = sqrt(2) Im Y_l^{|m|}`` (m < 0), ``Y_l^0`` (m = 0), ``sqrt(2) Re Y_l^m`` (m > 0).
(That is why ``Y_{1,-1} = -C1 y`` and ``Y_{1,1} = -C1 x``; tests/test_sh.py checks every basis
function against scipy's ``sph_harm_y``.)

Colours are ``SH . basis + 0.5`` (the DC term stores ``(rgb - 0.5) / C0``), see :func:`rgb_to_sh`.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["C0", "C1", "C2", "C3", "RGB2SH", "SH2RGB", "eval_sh", "num_sh_coeffs", "rgb_to_sh", "sh_basis", "sh_to_rgb"]

C0 = 0.28209479177387814  # 1 / (2 sqrt(pi))
C1 = 0.4886025119029199  # sqrt(3 / (4 pi))
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
    -0.4570457994644658, 1.445305721320277, -0.5900435899266435,
)


def num_sh_coeffs(degree: int) -> int:
    """Number of basis functions up to ``degree``: ``(degree + 1)^2``."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Real SH basis ``[..., (degree+1)^2]`` at unit directions ``dirs [..., 3]`` (normalised here)."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be in 0..3, got {degree}")
    d = torch.nn.functional.normalize(dirs, dim=-1)
    x, y, z = d.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, -1)


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate SH colour (without the +0.5 offset).

    Args:
        degree: active degree 0..3; only the first ``(degree+1)^2`` coefficients are used.
        coeffs: ``[..., K, 3]`` with ``K >= (degree+1)^2``.
        dirs: ``[..., 3]`` viewing directions (any length; normalised here), broadcastable to coeffs.
    Returns:
        ``[..., 3]`` = ``sum_k coeffs[..., k, :] * Y_k(dirs)``.
    """
    k = num_sh_coeffs(degree)
    if coeffs.shape[-2] < k:
        raise ValueError(f"eval_sh: degree {degree} needs {k} coefficients, got shape {tuple(coeffs.shape)}")
    basis = sh_basis(degree, dirs)  # [..., k]
    return (basis[..., None] * coeffs[..., :k, :]).sum(-2)


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient that decodes to ``rgb``: ``(rgb - 0.5) / C0``."""
    return (rgb - 0.5) / C0


def sh_to_rgb(sh: Tensor) -> Tensor:
    """Colour of a DC coefficient: ``sh * C0 + 0.5``."""
    return sh * C0 + 0.5


RGB2SH = rgb_to_sh  # the names used by the official 3DGS code
SH2RGB = sh_to_rgb
