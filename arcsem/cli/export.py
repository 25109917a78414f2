"""``arcsem-export RUN [--mesh] [--viewer] [--out DIR]``: a mesh and a viewer folder from a finished run.

``--mesh``: TSDF fusion of the model's rendered depth over the training views
(:mod:`arcsem.mesh`), written as ``mesh.ply`` and ``mesh.glb`` (coloured: ``colored_mesh.*`` when
the run has a stage-2 model); ``--voxel`` and ``--trunc`` override the derived scale. ``--viewer``:
the folder layout 3DGS viewers load (``viewer/point_cloud/iteration_N/point_cloud.ply`` +
``cameras.json``; Gaussians only). Default: both. Output: ``RUN/export`` unless ``--out``;
the run's own files are never changed.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["export_run", "main"]


def export_run(run: str | Path, out: str | Path | None, mesh: bool, viewer: bool,
               overrides: dict | None = None) -> dict:
    """Export the grey (and, where present, coloured) model of ``run``; returns what was written."""
    from arcsem.mesh import export_mesh, mesh_config
    from arcsem.runs import has_colour, load_run

    run = Path(run)
    out = Path(out) if out is not None else run / "export"
    result: dict = {}
    for colored in ([False, True] if has_colour(run) else [False]):
        m = load_run(run, colored=colored)
        prefix = "colored_" if colored else ""
        if mesh:
            mc = mesh_config({**dict(m.cfg.get("mesh") or {}), **(overrides or {}), "enabled": True})
            result[f"{prefix}mesh"] = export_mesh(m.backbone, m.scene, out / f"{prefix}mesh", mc, progress=True)
        if viewer:
            split = m.scene.train
            try:
                result[f"{prefix}viewer"] = m.backbone.export_viewer(
                    str(out / f"{prefix}viewer"), split.cameras, split.names, m.scene.bounds.double().mean(0), m.steps)
            except NotImplementedError as exc:
                result[f"{prefix}viewer"] = {"note": str(exc)}
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="arcsem-export", description=__doc__.splitlines()[0])
    parser.add_argument("run", metavar="RUN", help="a run folder written by arcsem")
    parser.add_argument("--mesh", action="store_true", help="TSDF mesh (PLY + GLB)")
    parser.add_argument("--viewer", action="store_true", help="folder layout that 3DGS viewers load")
    parser.add_argument("--out", default=None, help="output folder (default RUN/export)")
    parser.add_argument("--voxel", type=float, default=None, help="voxel size in scene units (default: derived)")
    parser.add_argument("--trunc", type=float, default=None, help="truncation in voxels (default 6)")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    args = parser.parse_args(argv)
    mesh, viewer = (args.mesh, args.viewer) if (args.mesh or args.viewer) else (True, True)
    over = {k: v for k, v in (("voxel_size", args.voxel), ("trunc", args.trunc)) if v is not None}

    from arcsem.cli.errors import call_reporting_errors

    def run() -> int:
        result = export_run(args.run, args.out, mesh, viewer, over)
        for key, val in result.items():
            files = val.get("files") or [v for k, v in val.items() if k in ("ply", "cameras", "native_ply")]
            gt = val.get("gt")
            extra = f"; Chamfer {gt['chamfer_pct']:.2f} % of the specimen" if gt else ""
            print(f"{key}: " + (", ".join(files) or json.dumps(val)) + extra)
        return 0

    return call_reporting_errors(run, args.debug)


if __name__ == "__main__":
    sys.exit(main())
