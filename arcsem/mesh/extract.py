"""Mesh export of a trained model: render depth (and colour), fuse a TSDF, write PLY + GLB.

:func:`export_mesh` is what stage 1 (grey mesh), stage 2 (coloured mesh) and ``arcsem-export RUN
--mesh`` call. Views: every training view (as 2DGS's authors do) plus, with ``orbit_frames > 0``,
views on orbits around the specimen (:mod:`arcsem.orbit`) at ``orbit_elevations``, only over the
azimuths and elevations the training cameras span unless ``orbit_in_range`` is false; all rendered
with the mean ACT. The default is the training views only, measured best (docs/mesh.md). Foreground: the
dataset's specimen masks on training views where ``use_masks`` and the dataset has them, else the
rendered alpha >= ``alpha_min``; the rest of each image clears space (``carve``).

Scale: the voxel edge is ``voxel_factor`` x the training images' pixel footprint at the specimen
(median over the views: ``distance / f`` for pinhole, ``1 / f`` for orthographic cameras), unless
``voxel_size`` is given in scene units; the truncation is ``trunc`` voxels; the grid covers the
scene bounds (``Scene.bounds``) and is coarsened if it would exceed ``max_voxels``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..configs import MeshConfig
from .tsdf import TSDFVolume, extract_mesh, keep_components, make_grid

__all__ = ["MeshConfig", "check_mesh_config", "export_mesh", "fuse_views", "mesh_config", "pixel_footprint", "write_mesh"]


def mesh_config(raw: Any) -> MeshConfig:
    """A validated :class:`~arcsem.configs.MeshConfig` from a config node / dict / None (``arcsem-export``'s
    overrides; a run reads its own once: :attr:`arcsem.runconfig.RunConfig.mesh`)."""
    from ..runconfig import validated

    return validated(MeshConfig, raw, where="mesh")


def pixel_footprint(cams, centre: torch.Tensor) -> float:
    """Median size (scene units) of one pixel of ``cams`` at the point ``centre [3]``."""
    f = cams.K[:, 0, 0].double()
    if cams.is_ortho:
        return float((1.0 / f).median())
    dist = (cams.to(dtype=torch.float64).to_camera(centre.double()[None])[:, 0, 2]).abs()
    return float((dist / f).median())


def _views(scene, cfg: MeshConfig):
    """``[(cameras [1], mask [H, W] or None)]``: training views, then orbit views (mean ACT)."""
    import dataclasses

    from ..orbit import OrbitConfig, camera_angles, orbit_frame, orbit_on_frame

    train = scene.train
    cams = dataclasses.replace(train.cameras, image_ids=torch.full_like(train.cameras.image_ids, -1))
    masks = train.masks if cfg.use_masks else None
    views = [(cams[i:i + 1], None if masks is None else masks[i]) for i in range(len(train))]
    frame = orbit_frame(train.cameras, scene.bounds)
    az, el = camera_angles(train.cameras, frame)
    azimuth = (float(az.min()), float(az.max())) if cfg.orbit_in_range else (0.0, 360.0)
    for elev in cfg.orbit_elevations if cfg.orbit_frames > 0 else []:
        if cfg.orbit_in_range:
            elev = min(max(float(elev), float(el.min())), float(el.max()))
        orbit = orbit_on_frame(frame, train.cameras, OrbitConfig(frames=cfg.orbit_frames, elevation=elev,
                                                                 azimuth=azimuth))
        views += [(orbit[i:i + 1], None) for i in range(len(orbit))]
    return views


def check_mesh_config(rc: Any) -> None:
    """A stage check (:mod:`arcsem.stages`): the ``mesh`` group of the run's config ``rc`` against
    :class:`~arcsem.configs.MeshConfig`. Both stages end with a mesh, so a bad key stops the run before training, not
    after it; so does ``mesh.impl=cpp`` where the fused TSDF kernel cannot load."""
    mc = rc.mesh
    if mc.enabled and mc.impl == "cpp":
        from .fused import usable

        usable("cpp", "cpu")  # ConfigError when it cannot be built here


def fuse_views(backbone, scene, cfg: MeshConfig, progress: bool = False) -> tuple[TSDFVolume, dict]:
    """Render every view and fuse it; returns the volume and ``{"voxel", "trunc", "grid", "views"}``."""
    from tqdm import tqdm

    from ..visual import render_layers

    centre = scene.bounds.double().mean(0)
    voxel = cfg.voxel_size or cfg.voxel_factor * pixel_footprint(scene.train.cameras, centre)
    grid = make_grid(scene.bounds, voxel, pad=int(np.ceil(cfg.trunc)) + 1, max_voxels=cfg.max_voxels)
    vol = TSDFVolume(grid, cfg.trunc * grid.voxel, impl=cfg.impl)
    views = _views(scene, cfg)
    for cam, mask in tqdm(views, desc="mesh: fusing views", disable=not progress, leave=False):
        lay = render_layers(backbone, cam, cfg.alpha_min, normals=False)
        valid = lay["valid"][0]
        surface, empty = (valid, ~valid) if mask is None else (valid & mask.bool(), ~mask.bool())
        vol.integrate(cam, lay["depth"][0], surface, lay["rgb"][0], background=empty if cfg.carve else None)
    info = {"voxel": grid.voxel, "trunc": vol.trunc, "grid": list(grid.shape), "views": len(views),
            "orbit_views": len(views) - len(scene.train)}
    return vol, info


def write_mesh(stem: Path, verts: np.ndarray, faces: np.ndarray, colors: np.ndarray, formats: list[str]) -> list[str]:
    """Write ``stem.<fmt>`` for each format with trimesh (vertex colours as RGBA8); returns the paths."""
    import trimesh

    stem.parent.mkdir(parents=True, exist_ok=True)
    rgba = np.concatenate([(colors * 255 + 0.5).astype(np.uint8), np.full((len(colors), 1), 255, np.uint8)], 1)
    mesh = trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=rgba, process=False)
    paths = []
    for fmt in formats:
        path = stem.with_suffix(f".{fmt}")
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_bytes(mesh.export(file_type=fmt))
        tmp.replace(path)
        paths.append(str(path))
    return paths


def export_mesh(backbone, scene, out_stem: str | Path, cfg: MeshConfig | None = None, *,
                progress: bool = False, evaluate: bool = True, cache_dir: str | Path | None = None) -> dict:
    """Fuse, extract, clean and write the mesh of ``backbone``; with ``evaluate`` and the built-in
    scene, add its Chamfer distance to the ground truth (:mod:`.groundtruth`; its surface samples kept in
    ``cache_dir/groundtruth`` when given). Returns the metrics."""
    cfg = cfg or MeshConfig()
    t0 = time.perf_counter()
    vol, info = fuse_views(backbone, scene, cfg, progress)
    verts, faces, colors = extract_mesh(vol)
    verts, faces, colors, comp = keep_components(verts, faces, colors, cfg.min_component)
    info.update(comp, vertices=len(verts), faces=len(faces))
    if len(faces) == 0:
        return {**info, "files": [], "note": "no surface was fused (empty mesh)",
                "time_s": time.perf_counter() - t0}
    info["files"] = write_mesh(Path(out_stem), verts, faces, colors, cfg.formats)
    info["fuse_time_s"] = time.perf_counter() - t0
    if evaluate:
        gt = ground_truth_chamfer(scene, verts, faces, cfg.chamfer_points, cache_dir)
        if gt is not None:
            info["gt"] = gt
    info["time_s"] = time.perf_counter() - t0
    return info


def ground_truth_chamfer(scene, verts: np.ndarray, faces: np.ndarray, n: int,
                         cache_dir: str | Path | None = None) -> dict | None:
    """Chamfer distance of the mesh to the built-in grain (None for other datasets); the grain's surface samples
    are read from (or kept in) ``cache_dir/groundtruth`` when given."""
    from .groundtruth import cached_surface_samples, chamfer, scene_grain, visible_samples

    grain = scene_grain(scene)
    split = scene.train
    if grain is None or split.depths is None:
        return None
    gt = cached_surface_samples(grain, None if cache_dir is None else Path(cache_dir) / "groundtruth")
    tol = 2.0 * pixel_footprint(split.cameras, scene.bounds.double().mean(0))
    out = chamfer(grain, verts, faces, gt[visible_samples(gt, split, tol)], n_mesh=n)
    out["visible_tol"] = tol
    return out
