"""Truncated signed distance fusion of depth maps, marching cubes, connected-component clean-up.

The functional core of mesh export (what 2DGS's authors do with Open3D's ``ScalableTSDFVolume``,
written here in PyTorch + scikit-image; ``docs/mesh.md`` gives the measured comparison):

* a dense voxel grid over a box; each voxel centre is projected into every view with
  :meth:`arcsem.cameras.Cameras.project` (pinhole and orthographic alike); where the view has a
  depth ``d`` at that pixel, the voxel gets the observation ``clamp((d - z) / trunc, -1, 1)``
  (``z``: the voxel's camera depth), unless it lies more than ``trunc`` behind the surface;
  observations are averaged with unit weights (Curless & Levoy 1996), colours likewise within
  ``trunc`` of the surface;
* ``carve``: a pixel that the view marks as background (no specimen) clears the voxels that project
  onto it (observation ``+1``), which removes floaters that one view sees and others see through;
* marching cubes (scikit-image) at level 0, triangles kept in cells whose 8 corners were all
  observed (unobserved space makes no surface), vertex colours trilinear from the colour grid;
* clean-up: connected components with fewer than ``min_component`` x the largest one's faces are
  dropped.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..cameras import Cameras

__all__ = ["Grid", "TSDFVolume", "extract_mesh", "keep_components", "make_grid"]


@dataclass
class Grid:
    """A voxel grid: ``origin [3]`` (centre of voxel ``(0,0,0)``), ``voxel`` edge, ``shape (X, Y, Z)``."""

    origin: Tensor
    voxel: float
    shape: tuple[int, int, int]

    def centres(self, start: int, stop: int) -> Tensor:
        """World centres ``[stop - start, 3]`` of the voxels with flat indices ``start..stop`` (C order)."""
        idx = torch.arange(start, stop, dtype=torch.long)
        _, Y, Z = self.shape
        ijk = torch.stack([idx // (Y * Z), (idx // Z) % Y, idx % Z], -1)
        return self.origin + ijk.to(torch.float64) * self.voxel


def make_grid(bounds: Tensor, voxel: float, pad: int = 2, max_voxels: int = 2**24) -> Grid:
    """A grid covering ``bounds [2, 3]`` plus ``pad`` voxels per side; the voxel grows if the grid
    would exceed ``max_voxels`` (memory: 20 bytes a voxel)."""
    lo, hi = bounds[0].double(), bounds[1].double()
    while True:
        shape = tuple(int(n) for n in torch.ceil((hi - lo) / voxel).long() + 1 + 2 * pad)
        if shape[0] * shape[1] * shape[2] <= max_voxels:
            break
        voxel *= 1.1
    return Grid(lo - pad * voxel, float(voxel), shape)  # type: ignore[arg-type]


class TSDFVolume:
    """Running TSDF, weight and colour on a :class:`Grid` (float32, flat C-order arrays)."""

    def __init__(self, grid: Grid, trunc: float, chunk: int = 1 << 21, impl: str = "auto"):
        """``impl``: ``auto|torch|cpp``, the path :meth:`integrate` takes (``mesh.impl``; :mod:`.fused`)."""
        from .fused import usable

        n = grid.shape[0] * grid.shape[1] * grid.shape[2]
        self.grid, self.trunc, self.chunk = grid, float(trunc), int(chunk)
        self.fused = usable(impl, "cpu")
        # voxel centres relative to the grid's centre, float32 (12 bytes a voxel): projecting relative
        # coordinates keeps float32 exact enough for cameras tens of specimen sizes away
        self.middle = grid.origin + (torch.tensor(grid.shape, dtype=torch.float64) - 1) / 2 * grid.voxel
        self.points = torch.cat([grid.centres(i, min(i + self.chunk, n)) - self.middle
                                 for i in range(0, n, self.chunk)]).float()
        self.tsdf = torch.ones(n, dtype=torch.float32)
        self.weight = torch.zeros(n, dtype=torch.float32)
        self.color = torch.zeros(n, 3, dtype=torch.float32)
        self.color_weight = torch.zeros(n, dtype=torch.float32)

    def integrate(self, cam: Cameras, depth: Tensor, valid: Tensor, rgb: Tensor | None = None,
                  background: Tensor | None = None) -> None:
        """Fuse one view: ``depth [H, W]`` z-depth, ``valid [H, W]`` bool (where ``depth`` is the
        surface), ``rgb [H, W, 3]`` or None, ``background [H, W]`` bool pixels that clear space, or None."""
        cam = _recentred(cam[:1], self.middle)
        H, W = depth.shape
        # one value per pixel, read once per voxel: the depth where valid, +inf where the pixel clears space
        # (background), NaN where it says nothing; a last entry (NaN) for voxels outside the view
        valid = valid.reshape(-1).bool()
        table = torch.where(valid, depth.float().reshape(-1), torch.tensor(float("nan")))
        if background is not None:
            table = torch.where(background.reshape(-1).bool() & ~valid, torch.tensor(float("inf")), table)
        table = torch.cat([table, table.new_tensor([float("nan")])])
        rgb = rgb.float().reshape(-1, 3) if rgb is not None else None
        if self.fused and table.device.type == "cpu" and cam.K.device.type == "cpu":
            from .fused import integrate

            integrate(self.points, cam.world_to_cam[0, :3], cam.K[0], bool(cam.is_ortho), W, H, table.contiguous(),
                      None if rgb is None else rgb.contiguous(), self.trunc, self.tsdf, self.weight, self.color,
                      self.color_weight)
            return
        n = self.tsdf.numel()
        for start in range(0, n, self.chunk):
            stop = min(start + self.chunk, n)
            uv, z = cam.project(self.points[start:stop])
            u, v, z = uv[0, :, 0].floor().long(), uv[0, :, 1].floor().long(), z[0]
            inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & ((z > 0) | cam.is_ortho)
            pix = torch.where(inside, v * W + u, H * W)
            sdf = table[pix] - z  # NaN: no observation; +inf: free space
            hit = sdf >= -self.trunc  # a surface at most trunc in front of the voxel, or free space
            obs = (sdf / self.trunc).clamp(-1.0, 1.0)  # (free space: +1)
            w = self.weight[start:stop]
            self.tsdf[start:stop] = torch.where(hit, (self.tsdf[start:stop] * w + obs) / (w + 1), self.tsdf[start:stop])
            self.weight[start:stop] = w + hit
            if rgb is not None:
                near = torch.nonzero(sdf.abs() < self.trunc)[:, 0]  # (finite: a surface pixel)
                self._update_color(start + near, rgb[pix[near]])

    def _update_color(self, idx: Tensor, rgb: Tensor) -> None:
        w = self.color_weight[idx][:, None]
        self.color[idx] = (self.color[idx] * w + rgb) / (w + 1)
        self.color_weight[idx] += 1

    def volumes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``tsdf [X, Y, Z]``, ``weight [X, Y, Z]``, ``color [X, Y, Z, 3]`` as numpy arrays."""
        s = self.grid.shape
        return self.tsdf.reshape(s).numpy(), self.weight.reshape(s).numpy(), self.color.reshape(*s, 3).numpy()


def _recentred(cam: Cameras, middle: Tensor) -> Cameras:
    """float32 camera of points given relative to ``middle [3]`` (the translation absorbs the offset)."""
    from dataclasses import replace

    w2c = cam.world_to_cam.double().clone()
    w2c[:, :3, 3] += (w2c[:, :3, :3] @ middle.double()[:, None])[..., 0]
    return replace(cam, world_to_cam=w2c.float(), K=cam.K.float())


def _observed_cells(weight: np.ndarray) -> np.ndarray:
    """``[X-1, Y-1, Z-1]`` bool: the cell between voxels ``(i..i+1, j..j+1, k..k+1)`` has all 8 corners observed."""
    w = weight > 0
    cell = w[:-1, :-1, :-1].copy()
    for dx, dy, dz in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)):
        cell &= w[dx:w.shape[0] - 1 + dx, dy:w.shape[1] - 1 + dy, dz:w.shape[2] - 1 + dz]
    return cell


def extract_mesh(vol: TSDFVolume) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Marching cubes of the fused TSDF: vertices ``[V, 3]`` (world), faces ``[F, 3]`` (int64, outward
    normals), vertex colours ``[V, 3]`` in [0, 1]. Empty arrays when no surface was observed.

    Triangles are kept only in cells whose 8 corners were all observed: an unobserved corner (tsdf
    1) next to observed inside values would make a spurious surface at the back of the truncation band.
    """
    from scipy.ndimage import map_coordinates
    from skimage.measure import marching_cubes

    tsdf, weight, color = vol.volumes()
    cells = _observed_cells(weight)
    empty = np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3))
    if not cells.any() or tsdf[weight > 0].min() >= 0 or tsdf[weight > 0].max() <= 0:
        return empty
    # scikit-image's default ("descent") orients the faces outwards for tsdf < 0 inside (tested)
    verts, faces, _, _ = marching_cubes(tsdf, level=0.0, allow_degenerate=False)
    cell = np.floor(verts[faces].mean(1)).astype(np.int64)  # the cell each triangle lies in
    cell = np.minimum(cell, np.array(cells.shape) - 1)
    faces = faces[cells[cell[:, 0], cell[:, 1], cell[:, 2]]]
    if len(faces) == 0:
        return empty
    used = np.unique(faces)
    remap = np.full(len(verts), -1, np.int64)
    remap[used] = np.arange(len(used))
    verts, faces = verts[used], remap[faces]
    seen = (vol.color_weight.reshape(tsdf.shape) > 0).numpy().astype(np.float32)
    den = map_coordinates(seen, verts.T, order=1, mode="nearest")
    cols = np.stack([map_coordinates(color[..., c] * seen, verts.T, order=1, mode="nearest") for c in range(3)], -1)
    cols = cols / np.maximum(den, 1e-6)[:, None]  # average of the coloured corners only
    world = verts * vol.grid.voxel + vol.grid.origin.numpy()
    return world, faces.astype(np.int64), np.clip(cols, 0.0, 1.0)


def keep_components(verts: np.ndarray, faces: np.ndarray, colors: np.ndarray, min_fraction: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Drop connected components with fewer than ``min_fraction`` x the largest one's faces.

    Returns the kept mesh (vertices re-indexed) and ``{"components", "kept", "faces_removed"}``.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(faces) == 0:
        return verts, faces, colors, {"components": 0, "kept": 0, "faces_removed": 0}
    a, b = np.concatenate([faces[:, 0], faces[:, 1]]), np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(verts), len(verts)))
    n, label = connected_components(graph, directed=False)
    face_label = label[faces[:, 0]]
    sizes = np.bincount(face_label, minlength=n)
    keep_label = sizes >= min_fraction * sizes.max()
    keep_face = keep_label[face_label]
    used = np.zeros(len(verts), bool)
    used[faces[keep_face].ravel()] = True
    remap = np.cumsum(used) - 1
    info = {"components": int((sizes > 0).sum()), "kept": int(keep_label.sum()),
            "faces_removed": int((~keep_face).sum())}
    return verts[used], remap[faces[keep_face]], colors[used], info
