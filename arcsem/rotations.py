"""Rotations as unit quaternions ``(w, x, y, z)`` and as matrices: the one implementation of both directions."""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["quat_to_rotmat", "rotmat_to_quat"]


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Quaternions ``[..., 4]`` (w, x, y, z; any non-zero norm) -> rotation matrices ``[..., 3, 3]``."""
    w, x, y, z = torch.nn.functional.normalize(q, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(R: Tensor) -> Tensor:
    """Rotation matrices ``[..., 3, 3]`` (one ``[3, 3]`` too) -> unit quaternions ``[..., 4]`` (w, x, y, z) with
    ``w >= 0`` (float64).

    Of the four algebraically equal candidates, the one built on the largest diagonal term is used (stable)."""
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"rotmat_to_quat: expected rotation matrices [..., 3, 3], got shape {tuple(R.shape)}")
    m = [[R[..., i, j].double() for j in range(3)] for i in range(3)]
    cands = torch.stack([
        torch.stack([1 + m[0][0] + m[1][1] + m[2][2], m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]], -1),
        torch.stack([m[2][1] - m[1][2], 1 + m[0][0] - m[1][1] - m[2][2], m[0][1] + m[1][0], m[0][2] + m[2][0]], -1),
        torch.stack([m[0][2] - m[2][0], m[0][1] + m[1][0], 1 - m[0][0] + m[1][1] - m[2][2], m[1][2] + m[2][1]], -1),
        torch.stack([m[1][0] - m[0][1], m[0][2] + m[2][0], m[1][2] + m[2][1], 1 - m[0][0] - m[1][1] + m[2][2]], -1),
    ], -2)  # [..., 4 candidates, 4]; candidate k is 4 * q_k * q
    best = cands.diagonal(dim1=-2, dim2=-1).argmax(-1)  # [...]
    q = torch.take_along_dim(cands, best[..., None, None].expand(*best.shape, 1, 4), -2)[..., 0, :]
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)
