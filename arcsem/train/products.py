"""What a finished stage leaves for people besides metrics: a mesh and a folder 3DGS viewers load.

:func:`write_products` runs at the end of stage 1 (grey: ``mesh.ply``/``.glb``, ``viewer/``) and of
stage 2 (``colored_`` prefix: the coloured mesh and viewer folder). The mesh needs a backbone that
renders depth (every in-tree one; :mod:`arcsem.mesh`, the ``mesh`` config block); the viewer folder
needs Gaussians (:meth:`arcsem.plugins.Backbone.export_viewer`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["write_products"]


def write_products(cfg: Any, backbone, scene, run_dir: str | Path, prefix: str = "", iteration: int = 0,
                   progress: bool = False, evaluate: bool = True) -> dict:
    """Write ``<prefix>mesh.*`` and ``<prefix>viewer/`` into ``run_dir``; returns their metrics and paths.
    ``evaluate``: score the mesh against the built-in scene's true surface (:func:`arcsem.mesh.export_mesh`)."""
    from ..mesh import export_mesh
    from ..runconfig import cache_root, run_config

    run_dir = Path(run_dir)
    rc = run_config(cfg)
    mc = rc.mesh  # a run's: validated once, however many products it writes
    out: dict[str, Any] = {}
    if mc.enabled and "depth" in backbone.provides:
        out["mesh"] = export_mesh(backbone, scene, run_dir / f"{prefix}mesh", mc, progress=progress, evaluate=evaluate,
                                  cache_dir=cache_root(rc.cfg))
    split = scene.train
    try:
        out["viewer"] = backbone.export_viewer(str(run_dir / f"{prefix}viewer"), split.cameras, split.names,
                                               scene.bounds.double().mean(0), iteration)
    except NotImplementedError:
        pass
    return out
