"""Surface texture of the synthetic SEM scene: fixed to the specimen and the substrate, so every view sees it alike.

Real SEM images carry fine structure everywhere (surface roughness, sputter grains, debris on the stub): it is
what feature matchers (SIFT) lock onto when a tilt series is calibrated, and what keeps every pixel of a
rasteriser busy. :func:`texture_gain` is a multiplicative gain on the secondary-electron yield, from 3-D value
noise (a hashed integer lattice, smoothstep-interpolated) summed over octaves. Pure function; shapes in the
docstrings.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["texture_gain", "value_noise"]

_PRIMES = (73856093, 19349663, 83492791)


def _lattice(ijk: Tensor, seed: int) -> Tensor:
    """Hash of integer lattice points ``ijk [..., 3]`` int64 -> uniform values in ``[0, 1)`` ``[...]``."""
    h = (ijk[..., 0] * _PRIMES[0]) ^ (ijk[..., 1] * _PRIMES[1]) ^ (ijk[..., 2] * _PRIMES[2]) ^ (seed * 2654435761)
    h = (h ^ (h >> 13)) * 1274126177  # integer mixing (wraps in int64: fine for a hash)
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).double() / float(1 << 24)


def value_noise(p: Tensor, seed: int) -> Tensor:
    """Smooth noise ``[N]`` in ``[0, 1]`` at points ``p [N, 3]`` (lattice spacing 1): trilinear blend of the
    eight corners' hashed values with smoothstep weights (continuous, with continuous first derivatives)."""
    p = p.double()
    base = torch.floor(p)
    f = p - base
    w = f * f * (3 - 2 * f)
    base = base.long()
    out = torch.zeros(len(p), dtype=torch.float64)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                corner = base + torch.tensor([dx, dy, dz])
                wx = w[:, 0] if dx else 1 - w[:, 0]
                wy = w[:, 1] if dy else 1 - w[:, 1]
                wz = w[:, 2] if dz else 1 - w[:, 2]
                out += wx * wy * wz * _lattice(corner, seed)
    return out


def texture_gain(p: Tensor, amplitude: float, scale: float, seed: int, octaves: int = 4) -> Tensor:
    """Gain ``[N]`` (float32) of surface points ``p [N, 3]``: ``1 + amplitude * n(p)`` with ``n`` in ``[-1, 1]``.

    ``n`` is value noise summed over ``octaves`` (lattice spacing ``scale``, then halved per octave, weights
    halved too, normalised to ``[-1, 1]``). ``amplitude = 0`` returns ones (the untextured scene, bitwise).
    """
    if amplitude == 0:
        return torch.ones(len(p), dtype=torch.float32)
    total, norm = torch.zeros(len(p), dtype=torch.float64), 0.0
    for o in range(octaves):
        weight = 0.5 ** o
        total += weight * (2 * value_noise(p.double() * (2 ** o / scale), seed + 101 * o) - 1)
        norm += weight
    return (1 + amplitude * total / norm).float()
