"""A third procedural specimen coloured by its parts, as an SEM artist colours a micrograph.

World axes as for the grain (``z`` up, the body centred at the origin, size 2 units). Construction
(signed distance, vectorised torch, deterministic per seed):

* body: an oblate ellipsoid (radii ``body_radii``) with ``n_pores`` pores (spherical dimples, subtracted)
  on Fibonacci directions;
* spines: ``n_spines`` capsules standing on the body along its normals, on the Fibonacci directions
  between the pores;
* debris: ``n_debris`` small spheres lying on the substrate around the body (part of the specimen: they
  are in the masks);
* substrate: the plane ``z = substrate_z``, shaded like the grain's but with its own colour.

Colour is a function of the part alone (``palette``: uniform body, spines, pores, debris and substrate
of distinct hues), never of latitude or shading: the SEM grey (geometry only) does not reveal it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from .sdf import ellipsoid, fibonacci_sphere

__all__ = ["PALETTE", "PART_NAMES", "Parts", "make_parts", "parts_albedo", "parts_label", "parts_sdf"]

PALETTE = {  # an artist's choice: one colour per part, hues far apart
    "body": (0.20, 0.35, 0.85),       # blue
    "spine": (0.95, 0.55, 0.08),      # orange
    "pore": (0.75, 0.10, 0.45),       # magenta
    "debris": (0.25, 0.80, 0.25),     # green
    "substrate": (0.85, 0.78, 0.45),  # sand
}
PART_NAMES = ("body", "spine", "pore", "debris")  # labels 0..3 of :func:`parts_label`


@dataclass
class Parts:
    """Parameters of one specimen (lengths in world units; arrays float64, tensors built per call).

    Attributes:
        pore_centres: ``[P, 3]`` centres of the pore spheres (on the body's surface).
        spine_base, spine_tip: ``[S, 3]`` the capsules' end points.
        debris: ``[D, 4]`` centre and radius of each debris sphere.
    """

    pore_centres: np.ndarray
    spine_base: np.ndarray
    spine_tip: np.ndarray
    debris: np.ndarray
    body_radii: tuple[float, float, float] = (0.85, 0.85, 0.62)
    pore_r: float = 0.10
    spine_r: float = 0.045
    substrate_z: float = -0.85
    size: float = 2.0
    palette: dict = field(default_factory=lambda: dict(PALETTE))
    dtype: torch.dtype = torch.float64  # of the tensors it hands out (radii, aabb); its SDF follows the points

    @property
    def radii(self) -> Tensor:
        """``[3]`` the body's ellipsoid (the substrate's analytic detector shadow)."""
        return torch.tensor(self.body_radii, dtype=self.dtype)

    @property
    def substrate_albedo(self) -> tuple[float, float, float]:
        """The substrate's colour (:func:`arcsem.synthetic.render.shade` reads it when a specimen has one)."""
        return self.palette["substrate"]

    @property
    def bound_radius(self) -> float:
        """Radius of a sphere around the origin that holds every part."""
        tips = np.linalg.norm(self.spine_tip, axis=-1).max() + self.spine_r
        debris = (np.linalg.norm(self.debris[:, :3], axis=-1) + self.debris[:, 3]).max() if len(self.debris) else 0
        return float(max(tips, debris, max(self.body_radii)) + 0.05)

    @property
    def aabb(self) -> Tensor:
        """``[2, 3]`` box (min, max) that holds every part."""
        pts = [np.diag(self.body_radii), -np.diag(self.body_radii), self.spine_tip + self.spine_r,
               self.spine_tip - self.spine_r, self.debris[:, :3] + self.debris[:, 3:], self.debris[:, :3] - self.debris[:, 3:]]
        pts = np.concatenate(pts)
        return torch.tensor(np.stack([pts.min(0) - 0.02, pts.max(0) + 0.02]), dtype=self.dtype)

    def to(self, dtype: torch.dtype) -> Parts:
        return replace(self, dtype=dtype)

    def sdf(self, p: Tensor) -> Tensor:
        """Signed distance ``[N]`` of points ``p [N, 3]`` (negative inside)."""
        return parts_sdf(self, p)["sdf"]

    def albedo(self, p: Tensor) -> Tensor:
        """RGB albedo ``[N, 3]`` of surface points (:func:`parts_albedo`)."""
        return parts_albedo(self, p)


def make_parts(seed: int = 0, n_pores: int = 10, n_spines: int = 14, n_debris: int = 5) -> Parts:
    """A specimen whose pores, spines and debris are placed by ``seed`` (a random turn of the pattern)."""
    rng = np.random.default_rng(seed)
    radii = np.array(Parts.body_radii)
    turn = rng.uniform(0, 2 * math.pi)
    c, s = math.cos(turn), math.sin(turn)
    dirs = fibonacci_sphere(n_pores + n_spines) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    dirs = dirs[dirs[:, 2] > -0.75]  # nothing under the body, where no view looks
    on_body = dirs / np.linalg.norm(dirs / radii, axis=-1, keepdims=True)
    normal = on_body / radii**2
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    pore = np.arange(len(dirs)) % 3 == 0  # every third direction a pore, the others spines
    length = rng.uniform(0.28, 0.38, int((~pore).sum()))
    base = on_body[~pore] - 0.05 * normal[~pore]
    ang = turn + np.linspace(0, 2 * math.pi, n_debris, endpoint=False) + rng.uniform(-0.3, 0.3, n_debris)
    rad = rng.uniform(1.05, 1.3, n_debris)
    size = rng.uniform(0.06, 0.1, n_debris)
    debris = np.stack([rad * np.cos(ang), rad * np.sin(ang), Parts.substrate_z + size, size], -1)
    return Parts(pore_centres=on_body[pore], spine_base=base, spine_tip=base + length[:, None] * normal[~pore],
                 debris=debris)


def _capsules(p: Tensor, a: Tensor, b: Tensor, r: float) -> Tensor:
    """Distance ``[N]`` of ``p [N, 3]`` to the nearest of the capsules ``a -> b`` (``[S, 3]`` each)."""
    ab = b - a                                                        # [S, 3]
    t = (((p[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1)).clamp(0, 1)  # [N, S]
    return (p[:, None] - a - t[..., None] * ab).norm(dim=-1).min(-1).values - r


def parts_sdf(g: Parts, p: Tensor) -> dict[str, Tensor]:
    """Signed distance ``sdf [N]`` of ``p [N, 3]`` and of its parts: ``shell`` (the ellipsoid), ``pore`` (the
    nearest pore sphere), ``body`` (shell minus pores), ``spine`` and ``debris`` (each ``[N]``)."""
    t = lambda a: torch.as_tensor(a, dtype=p.dtype, device=p.device)
    shell = ellipsoid(p, t(g.body_radii))
    pore = torch.cdist(p, t(g.pore_centres)).min(-1).values - g.pore_r
    body = torch.maximum(shell, -pore)
    spine = _capsules(p, t(g.spine_base), t(g.spine_tip), g.spine_r)
    deb = t(g.debris)
    debris = (torch.cdist(p, deb[:, :3]) - deb[:, 3]).min(-1).values
    sdf = torch.minimum(torch.minimum(body, spine), debris)
    return {"sdf": sdf, "shell": shell, "pore": pore, "body": body, "spine": spine, "debris": debris}


def parts_label(g: Parts, p: Tensor) -> Tensor:
    """``[N]`` the part (index into :data:`PART_NAMES`) of surface points ``p [N, 3]``: the part whose surface
    is nearest; on the body, ``pore`` where the pore carves it (its wall and floor)."""
    d = parts_sdf(g, p)
    near = torch.stack([d["body"].abs(), d["spine"].abs(), d["debris"].abs()], -1).argmin(-1)  # body, spine, debris
    label = torch.where(near == 2, torch.full_like(near, 3), near)
    return torch.where((label == 0) & (-d["pore"] >= d["shell"]), torch.full_like(label, 2), label)


def parts_albedo(g: Parts, p: Tensor) -> Tensor:
    """RGB albedo ``[N, 3]`` in [0, 1] of surface points ``p [N, 3]``: the palette colour of each point's part."""
    table = torch.tensor([g.palette[n] for n in PART_NAMES], dtype=p.dtype, device=p.device)
    return table[parts_label(g, p)]
