"""Ground-truth surface of the built-in scene, and the mesh's Chamfer distance to it.

The grain is rebuilt from the ``synthetic`` block of the scene's ``transforms.json`` (seed and
spine count: :func:`arcsem.synthetic.sdf.make_grain` is deterministic). Its surface is sampled
from the signed distance function: marching cubes on a fine grid, points drawn on the triangles
by area, then projected onto the zero set with Newton steps (the SDF is exact near the surface).

Chamfer protocol (as the DTU evaluation, with the SDF's surface as the scan):

* **accuracy**: mean distance from points sampled on the mesh to the whole ground-truth surface
  (every part of the mesh is judged, including parts no training view saw): ``|sdf|`` at the points,
  exact within ``blend + 0.03`` (0.07 units) of the surface and a lower bound farther away;
* **completeness**: mean distance from the ground-truth surface *seen by a training view* (a
  sample counts where, in some training view, it projects inside the specimen mask at the
  ground-truth depth of its pixel, within ``visible_tol``) to the nearest of dense samples on the
  mesh; no method can be asked for surface that no view shows;
* **chamfer**: their mean. All in scene units and in % of the grain's diameter.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

__all__ = ["cached_surface_samples", "chamfer", "sample_mesh", "scene_grain", "surface_samples", "visible_samples"]


def scene_grain(scene):
    """The built-in scene's :class:`~arcsem.synthetic.sdf.Grain`, or None for any other dataset."""
    from ..synthetic.sdf import make_grain

    path = Path(scene.root) / "transforms.json"
    if not path.is_file():
        return None
    try:
        syn = json.loads(path.read_text()).get("synthetic")
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(syn, dict):
        return None
    return make_grain(int(syn.get("seed", 0)), int(syn.get("n_spines", 30)))


def sample_mesh(verts: np.ndarray, faces: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """``n`` points ``[n, 3]`` drawn uniformly by area on the triangles ``faces [F, 3]`` of ``verts [V, 3]``."""
    rng = np.random.default_rng(seed)
    tri = verts[faces]  # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    pick = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], -1)  # uniform barycentric weights
    return (tri[pick] * w[..., None]).sum(1)


def _sdf_chunked(grain, p: Tensor, chunk: int = 1 << 18) -> Tensor:
    return torch.cat([grain.sdf(p[i:i + chunk]) for i in range(0, len(p), chunk)])


def surface_samples(grain, n: int = 200_000, spacing: float = 0.025, newton: int = 2, seed: int = 0) -> np.ndarray:
    """``[n, 3]`` float64 points on the grain's surface (``|sdf| < 1e-6`` after projection)."""
    from skimage.measure import marching_cubes

    from ..synthetic.trace import sdf_gradient

    lo, hi = grain.aabb[0] - 2 * spacing, grain.aabb[1] + 2 * spacing
    axes = [torch.arange(float(lo[k]), float(hi[k]) + spacing, spacing, dtype=torch.float64) for k in range(3)]
    pts = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)
    vol = _sdf_chunked(grain, pts.reshape(-1, 3)).reshape(pts.shape[:3]).numpy()
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(spacing,) * 3)
    p = torch.from_numpy(sample_mesh(verts + lo.numpy(), faces, n, seed))
    for _ in range(newton):
        for i in range(0, len(p), 1 << 18):
            q = p[i:i + (1 << 18)]
            normal, _ = sdf_gradient(grain.sdf, q)
            p[i:i + (1 << 18)] = q - grain.sdf(q)[:, None] * normal
    return p.numpy()


def cached_surface_samples(grain, cache_dir: str | Path | None, **kw) -> np.ndarray:
    """:func:`surface_samples` of ``grain`` (``kw`` its settings), read from ``cache_dir`` when it holds them (keyed
    by the grain, the settings and the scene generator's version), else computed and kept there (None: no cache).
    The samples are the same every run on the built-in scene, and most of the Chamfer score's time."""
    import hashlib
    import logging

    from ..files import atomic_open
    from ..synthetic.write import GENERATOR_VERSION

    if cache_dir is None:
        return surface_samples(grain, **kw)
    h = hashlib.sha1(json.dumps({"settings": kw, "generator": GENERATOR_VERSION}, sort_keys=True).encode())
    for f in dataclasses.fields(grain):  # the grain itself, by content
        h.update(f.name.encode())
        h.update(torch.as_tensor(getattr(grain, f.name)).double().contiguous().numpy().tobytes())
    path = Path(cache_dir) / f"surface_{h.hexdigest()[:16]}.npy"
    if path.is_file():
        try:
            return np.load(path)
        except (OSError, ValueError) as exc:  # a damaged cache file is recomputed, not fatal
            logging.getLogger(__name__).warning("ground-truth cache %s unreadable (%s); recomputing", path, exc)
    points = surface_samples(grain, **kw)
    with atomic_open(path, "wb") as f:
        np.save(f, points)
    return points


def visible_samples(points: np.ndarray, split, tol: float) -> np.ndarray:
    """``[P]`` bool: the point is seen by some view of ``split`` (needs ``masks`` and ``depths``)."""
    p = torch.from_numpy(points)
    seen = torch.zeros(len(p), dtype=torch.bool)
    cams = split.cameras.to(dtype=torch.float64)
    H, W = cams.height, cams.width
    for i in range(len(split)):
        uv, z = cams[i:i + 1].project(p)
        u, v, z = uv[0, :, 0].floor().long(), uv[0, :, 1].floor().long(), z[0]
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        u, v = u.clamp(0, W - 1), v.clamp(0, H - 1)
        gt = split.depths[i].double()[v, u]
        ok = inside & (gt > 0) & ((gt - z).abs() < tol)
        if split.masks is not None:
            ok &= split.masks[i][v, u].bool()
        seen |= ok
    return seen.numpy()


def chamfer(grain, verts: np.ndarray, faces: np.ndarray, gt_seen: np.ndarray, n_mesh: int = 1_000_000,
            n_accuracy: int = 300_000) -> dict:
    """Accuracy, completeness and Chamfer distance of a mesh (see the module docstring), also in % of
    the grain's size."""
    from scipy.spatial import cKDTree

    pts = sample_mesh(verts, faces, n_mesh, seed=1)
    acc = _sdf_chunked(grain, torch.from_numpy(pts[:n_accuracy])).abs().numpy()
    comp = cKDTree(pts).query(gt_seen, workers=-1)[0]
    out = {"accuracy": float(acc.mean()), "completeness": float(comp.mean())}
    out["chamfer"] = 0.5 * (out["accuracy"] + out["completeness"])
    out.update({f"{k}_pct": 100.0 * out[k] / grain.size for k in ("accuracy", "completeness", "chamfer")})
    out.update(accuracy_median=float(np.median(acc)), completeness_median=float(np.median(comp)),
               mesh_points=len(pts), accuracy_points=len(acc), gt_seen_points=len(gt_seen), size=grain.size)
    return out
