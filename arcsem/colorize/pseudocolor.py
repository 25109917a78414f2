"""Pseudo-colours: reference colours carried to every other view through 3-D nearest neighbours.

1. The masked pixels of each reference view are unprojected with that view's depth
   (:meth:`arcsem.cameras.Cameras.unproject_points`) into 3-D points carrying the reference colour.
2. Every masked pixel of every other view is unprojected with its own depth; its pseudo-colour is
   the colour of the nearest reference point (``scipy.spatial.cKDTree``, all cores) if that point
   lies within a radius, else the pixel has none (``valid`` False).

The default radius is ``radius_factor`` (2) times the world size of one pixel at the query's depth
(orthographic: ``1/fx``; pinhole: ``z/fx``); a fixed world ``radius`` may be given instead.
Results are cached on disk under a hash of everything they depend on (atomic writes).
"""
from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..cameras import Cameras

__all__ = [
    "cache_key",
    "cached_pseudo_colors",
    "load_pseudo",
    "masked_points",
    "pixel_footprint",
    "pseudo_colors",
    "pseudo_key",
    "query_view",
    "reference_cloud",
    "render_depths",
    "save_pseudo",
]

log = logging.getLogger(__name__)


def render_depths(backbone, split, alpha_min: float = 0.5) -> torch.Tensor:
    """z-depth ``[N, H, W]`` of every view from the model (median depth if provided); 0 where alpha < alpha_min."""
    out = []
    with torch.no_grad():
        for i in range(len(split)):
            r = backbone.render(split.cameras[i:i + 1])
            d = r.get("median_depth", r["depth"])[0, ..., 0]
            a = r["alpha"][0, ..., 0] if "alpha" in r else torch.ones_like(d)
            out.append(torch.where(a >= alpha_min, d, torch.zeros_like(d)).cpu())
    return torch.stack(out)


def pixel_footprint(cams: Cameras, depth: Tensor) -> Tensor:
    """World size of one pixel ``[C, N]`` for depths ``[C, N]``: ortho ``1/fx``, pinhole ``z/fx``."""
    fx = cams.K[:, 0, 0].to(depth.dtype)[:, None]
    return (1.0 / fx).expand_as(depth) if cams.is_ortho else depth.abs() / fx


def masked_points(cam: Cameras, depth: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Unproject the masked pixels of ONE view.

    Args:
        cam: one camera. depth: ``[H, W]`` z-depth. mask: ``[H, W]`` bool (pixels with depth <= 0 are dropped).
    Returns:
        flat pixel indices ``[M]`` (long, row-major) and world points ``[M, 3]`` (float64).
    """
    mask = mask & (depth > 0)
    flat = mask.reshape(-1).nonzero()[:, 0]
    W = cam.width
    uv = torch.stack([(flat % W).double() + 0.5, (flat // W).double() + 0.5], -1)
    z = depth.reshape(-1)[flat].double()
    pts = cam.to(dtype=torch.float64).unproject_points(uv[None], z[None])[0]
    return flat, pts


def reference_cloud(cams: Cameras, depths: Tensor, masks: Tensor, images: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Coloured point cloud of the references.

    Args:
        cams: ``R`` reference cameras. depths: ``[R, H, W]``. masks: ``[R, H, W]`` bool.
        images: ``[R, H, W, C]`` reference colours (and any other channels).
    Returns:
        points ``[P, 3]`` float64 and colours ``[P, C]`` float32 (numpy).
    """
    pts, cols = [], []
    for r in range(len(cams)):
        flat, p = masked_points(cams[r], depths[r], masks[r])
        pts.append(p.numpy())
        cols.append(images[r].reshape(-1, images.shape[-1])[flat].float().numpy())
    return np.concatenate(pts), np.concatenate(cols)


def pseudo_colors(
    cams: Cameras,
    depths: Tensor,
    masks: Tensor,
    ref_indices: list[int],
    ref_images: Tensor,
    radius: float | None = None,
    radius_factor: float = 2.0,
    progress: bool = True,
) -> tuple[Tensor, Tensor]:
    """Pseudo-colours of every view.

    Args:
        cams: ``N`` cameras. depths: ``[N, H, W]`` (or ``[N, H, W, 1]``) z-depth, <= 0 = no surface.
        masks: ``[N, H, W]`` bool specimen masks. ref_indices: ``R`` indices into the ``N`` views.
        ref_images: ``[R, H, W, 3]`` colours of those views.
        radius: fixed world radius; default ``radius_factor`` x the pixel footprint of each query.
    Returns:
        colors ``[N, H, W, C]`` float32 (0 where invalid; ``C`` the channels of ``ref_images``, which may carry
        more than colour, e.g. the reference's grey) and valid ``[N, H, W]`` bool. Reference views get their own
        colours inside their masks.
    """
    from scipy.spatial import cKDTree
    from tqdm.auto import tqdm

    depths = depths[..., 0] if depths.ndim == 4 else depths
    N, H, W = depths.shape
    masks = masks.bool()
    ridx = list(ref_indices)
    pts, cols = reference_cloud(cams[torch.as_tensor(ridx)], depths[ridx], masks[ridx], ref_images)
    colors = torch.zeros(N, H, W, ref_images.shape[-1])
    valid = torch.zeros(N, H, W, dtype=torch.bool)
    if len(pts) == 0:
        log.warning("pseudo-colours: the reference masks are empty; no view gets a pseudo-colour")
        return colors, valid
    tree = cKDTree(pts, leafsize=16, balanced_tree=False, compact_nodes=False)
    cols_t = torch.from_numpy(cols)
    for v in tqdm(range(N), desc="pseudo-colours", disable=not progress, leave=False):
        if v in ridx:
            m = masks[v] & (depths[v] > 0)
            colors[v][m] = ref_images[ridx.index(v)].float()[m]
            valid[v] = m
            continue
        hit, nn = query_view(tree, cams[v], depths[v], masks[v], radius, radius_factor)
        colors[v].view(-1, colors.shape[-1])[hit] = cols_t[nn]
        valid[v].view(-1)[hit] = True
    return colors, valid


def query_view(tree, cam: Cameras, depth: Tensor, mask: Tensor, radius: float | None = None,
               radius_factor: float = 2.0) -> tuple[Tensor, Tensor]:
    """The masked pixels of ONE view (``depth``, ``mask`` ``[H, W]``) that have a reference point of
    ``tree`` (a ``cKDTree`` of the reference cloud) within the radius: flat pixel indices ``[M]`` and the
    index ``[M]`` of their nearest reference point."""
    flat, q = masked_points(cam, depth, mask)
    if len(flat) == 0:
        return flat, flat
    z = depth.reshape(-1)[flat].double()
    r = torch.full_like(z, radius) if radius is not None else radius_factor * pixel_footprint(cam, z[None])[0]
    dist, nn = tree.query(q.numpy(), k=1, distance_upper_bound=float(r.max()), workers=-1)
    ok = torch.from_numpy(dist <= r.numpy())
    return flat[ok], torch.from_numpy(nn[ok.numpy()])


# ---------------------------------------------------------------- cache
def cache_key(*parts) -> str:
    """Hex digest over ``parts``: tensors/arrays (shape, dtype, bytes), bytes, file paths (bytes), numbers, strings."""
    h = hashlib.blake2b(digest_size=20)
    for p in parts:
        if isinstance(p, Tensor):
            p = p.detach().cpu().contiguous().numpy()
        if isinstance(p, np.ndarray):
            h.update(f"{p.shape}{p.dtype}".encode())
            h.update(memoryview(np.ascontiguousarray(p)).cast("B"))
        elif isinstance(p, (bytes, bytearray)):
            h.update(p)
        elif isinstance(p, Path):
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 24), b""):
                    h.update(chunk)
        elif isinstance(p, (list, tuple)):
            h.update(cache_key(*p).encode())
        else:
            h.update(repr(p).encode())
        h.update(b"|")
    return h.hexdigest()


def pseudo_key(depth_source, ref_images: Tensor, ref_names: list[str], radius: float | None,
               radius_factor: float, masks: Tensor, cams: Cameras) -> str:
    """Cache key of a pseudo-colour result.

    ``depth_source``: the stage-1 checkpoint file (its bytes are hashed) or the depth maps ``[N,H,W]``.
    Masks and cameras are part of the key too: changing either changes the answer.
    """
    src = Path(depth_source) if isinstance(depth_source, (str, Path)) else depth_source
    return cache_key("pseudo-v1", src, ref_images, list(ref_names), radius, radius_factor, masks,
                     cams.world_to_cam, cams.K, cams.model)


def save_pseudo(path: Path, colors: Tensor, valid: Tensor) -> None:
    """Write atomically: valid bits packed, colours only where valid."""
    from ..files import atomic_open

    with atomic_open(path, "wb") as f:
        np.savez(f, shape=np.array(valid.shape), valid=np.packbits(valid.numpy().reshape(-1)),
                 colors=colors[valid].float().numpy())


def load_pseudo(path: Path) -> tuple[Tensor, Tensor]:
    with np.load(path) as z:
        shape = tuple(int(s) for s in z["shape"])
        valid = torch.from_numpy(np.unpackbits(z["valid"], count=int(np.prod(shape))).astype(bool).reshape(shape))
        stored = torch.from_numpy(z["colors"])
        colors = torch.zeros(*shape, stored.shape[-1] if stored.ndim == 2 else 3)
        colors[valid] = stored
    return colors, valid


def cached_pseudo_colors(cache_dir: str | Path | None, key: str, compute: Callable[[], tuple[Tensor, Tensor]]):
    """``compute()`` unless ``cache_dir/pseudo_<key>.npz`` exists; returns ``(colors, valid, hit)``."""
    if cache_dir is None:
        return (*compute(), False)
    path = Path(cache_dir) / f"pseudo_{key}.npz"
    if path.exists():
        try:
            return (*load_pseudo(path), True)
        except (OSError, ValueError, KeyError) as exc:  # a corrupt cache file is recomputed, not fatal
            log.warning("pseudo-colour cache %s unreadable (%s); recomputing", path, exc)
    colors, valid = compute()
    save_pseudo(path, colors, valid)
    return colors, valid, False
