"""PLY export/import in the layout the common 3DGS viewers read (binary little-endian float32).

Vertex properties, in order (as written by the official 3DGS code):
``x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..(S-1) rot_0..3`` where

* ``f_rest`` is *channel-major*: ``f_rest_{c*(K-1)+k}`` is coefficient ``k+1`` of channel ``c``
  (45 values for SH degree 3);
* ``opacity`` is the logit, ``scale_*`` the log-scales, ``rot_*`` the quaternion (w, x, y, z);
* normals are written as zeros (viewers ignore them);
* 2DGS writes two scales (``scale_0, scale_1``) like the official 2DGS code; viewers made for
  3DGS expect three and may need a third (``log(0)``-like thin axis) added before loading.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from arcsem.errors import DataError
from arcsem.ply import read_vertices, write_vertices

__all__ = ["ply_properties", "read_ply", "write_ply"]


def ply_properties(num_rest: int, num_scales: int) -> list[str]:
    """Vertex property names; ``num_rest`` = number of higher SH coefficients per channel."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(3 * num_rest)]
        + ["opacity"] + [f"scale_{i}" for i in range(num_scales)] + [f"rot_{i}" for i in range(4)]
    )


def write_ply(path: str | Path, params: dict[str, Tensor]) -> None:
    """Write raw Gaussian parameters (see :mod:`.model`) to ``path`` (float32 properties, :func:`ply_properties`).

    Args:
        params: means ``[N,3]``, quats ``[N,4]``, log_scales ``[N,S]``, opacity_logits ``[N]``,
            sh_dc ``[N,1,3]``, sh_rest ``[N,K-1,3]``.
    """
    p = {k: v.detach().cpu().float() for k, v in params.items()}
    n = p["means"].shape[0]
    rest = p["sh_rest"].transpose(1, 2).reshape(n, -1)  # [N, 3, K-1] -> channel-major
    cols = [p["means"], torch.zeros(n, 3), p["sh_dc"].reshape(n, 3), rest, p["opacity_logits"].reshape(n, 1),
            p["log_scales"], p["quats"]]
    data = torch.cat(cols, 1).numpy().astype("<f4")
    names = ply_properties(p["sh_rest"].shape[1], p["log_scales"].shape[1])
    write_vertices(path, {name: data[:, j] for j, name in enumerate(names)})


def read_ply(path: str | Path) -> dict[str, Tensor]:
    """Read a 3DGS/2DGS PLY back into raw parameters (float32 tensors, shapes as in :func:`write_ply`)."""
    arr = read_vertices(path)
    names = set(arr)
    n = len(arr["x"]) if "x" in arr else 0

    def cols(prefix: str, count: int | None = None) -> np.ndarray:
        keys = sorted((k for k in names if k.startswith(prefix) and k[len(prefix):].isdigit()),
                      key=lambda k: int(k[len(prefix):]))
        if count is not None and len(keys) != count or not keys:
            raise DataError(f"{path}: expected {count or 'some'} '{prefix}*' properties, found {len(keys)}")
        return np.stack([arr[k].astype(np.float32) for k in keys], 1)

    missing = [k for k in ("x", "y", "z", "opacity") if k not in names]
    if missing:
        raise DataError(f"{path}: PLY lacks vertex properties {missing}")
    rest = cols("f_rest_") if any(k.startswith("f_rest_") for k in names) else np.zeros((n, 0), np.float32)
    if rest.shape[1] % 3 or math.isqrt(rest.shape[1] // 3 + 1) ** 2 != rest.shape[1] // 3 + 1:
        raise DataError(f"{path}: {rest.shape[1]} f_rest values is not 3 x ((d+1)^2 - 1)")
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))
    return {
        "means": t(np.stack([arr[k].astype(np.float32) for k in "xyz"], 1)),
        "quats": t(cols("rot_", 4)),
        "log_scales": t(cols("scale_")),
        "opacity_logits": t(arr["opacity"].astype(np.float32)),
        "sh_dc": t(cols("f_dc_", 3)).reshape(n, 1, 3),
        "sh_rest": t(rest.reshape(n, 3, -1)).transpose(1, 2).contiguous(),
    }
