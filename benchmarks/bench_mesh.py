"""Mesh export on a finished run: Chamfer distance to the built-in grain and time, for mesh settings
given as JSON (``MeshConfig`` fields), and optionally Open3D's TSDF on the same rendered views.

    .venv/bin/python benchmarks/bench_mesh.py RUN '{"orbit_frames": 0}' '{}'
    .venv/bin/python benchmarks/bench_mesh.py RUN '{"orbit_frames": 0}' --open3d-python /tmp/o3d-venv/bin/python

Open3D is not a dependency: ``--open3d-python`` names the interpreter of a separate venv with
``open3d-cpu`` (``python3 -m venv /tmp/o3d-venv && /tmp/o3d-venv/bin/pip install open3d-cpu``). The
training views are rendered here (median depth, masked as arcsem masks them), saved to an ``.npz``,
fused by Open3D's ``UniformTSDFVolume`` with the same voxel and truncation in that interpreter (its
``ScalableTSDFVolume``, which 2DGS's code uses, extracted nothing with open3d-cpu 0.20.0 here), and
its mesh is cleaned and scored here exactly as arcsem's own (pinhole cameras only: Open3D has no
orthographic camera). Results in docs/mesh.md.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

O3D_SCRIPT = r"""
import sys, numpy as np, open3d as o3d
d = np.load(sys.argv[1])
# UniformTSDFVolume over the scene bounds: ScalableTSDFVolume (what 2DGS's code uses) extracted nothing
# at all with open3d-cpu 0.20.0 here, not even a plane in front of an identity camera
vol = o3d.pipelines.integration.UniformTSDFVolume(length=float(d["length"]), resolution=int(d["resolution"]),
    sdf_trunc=float(d["trunc"]), color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8, origin=d["origin"])
for k in range(len(d["depth"])):
    K = d["K"][k]
    intr = o3d.camera.PinholeCameraIntrinsic(int(d["width"]), int(d["height"]), K[0, 0], K[1, 1], K[0, 2] - 0.5,
                                             K[1, 2] - 0.5)  # Open3D: pixel centres at integers
    rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.ascontiguousarray(d["rgb"][k])), o3d.geometry.Image(np.ascontiguousarray(d["depth"][k])),
        depth_scale=1.0, depth_trunc=1e9, convert_rgb_to_intensity=False)
    vol.integrate(rgbd, intr, d["w2c"][k])
mesh = vol.extract_triangle_mesh()
np.savez(sys.argv[2], verts=np.asarray(mesh.vertices), faces=np.asarray(mesh.triangles),
         colors=np.asarray(mesh.vertex_colors))
"""


def ours(m, cfg_json: str, out: Path) -> dict:
    from arcsem.mesh import MeshConfig, export_mesh

    t0 = time.perf_counter()
    info = export_mesh(m.backbone, m.scene, out / "mesh", MeshConfig(**json.loads(cfg_json)))
    return {"method": f"arcsem {cfg_json}", "time_s": time.perf_counter() - t0, **_summary(info)}


def _summary(info: dict) -> dict:
    gt = info.get("gt") or {}
    keys = ("chamfer_pct", "accuracy_pct", "completeness_pct", "accuracy_median", "completeness_median")
    return {"faces": info.get("faces"), **{k: gt.get(k) for k in keys}}


def open3d(m, cfg_json: str, python: str, tmp: Path) -> dict:
    """Open3D's TSDF on arcsem's renders of the training views (same voxel, truncation, masks)."""
    from arcsem.mesh import MeshConfig
    from arcsem.mesh.extract import ground_truth_chamfer, pixel_footprint
    from arcsem.mesh.tsdf import keep_components
    from arcsem.visual import render_layers

    cfg = MeshConfig(**json.loads(cfg_json))
    split = m.scene.train
    voxel = cfg.voxel_size or cfg.voxel_factor * pixel_footprint(split.cameras, m.scene.bounds.double().mean(0))
    depth, rgb = [], []
    cams = split.cameras
    cams.image_ids[:] = -1
    for i in range(len(split)):
        lay = render_layers(m.backbone, cams[i:i + 1], cfg.alpha_min, normals=False)
        ok = lay["valid"][0] & (split.masks[i].bool() if split.masks is not None else True)
        depth.append(torch.where(ok, lay["depth"][0], torch.zeros_like(lay["depth"][0])).numpy().astype(np.float32))
        rgb.append((lay["rgb"][0].numpy() * 255 + 0.5).astype(np.uint8))
    src, dst = tmp / "views.npz", tmp / "o3d_mesh.npz"
    lo, hi = m.scene.bounds[0].double().numpy(), m.scene.bounds[1].double().numpy()
    length = float((hi - lo).max()) + 2 * (cfg.trunc + 1) * voxel  # a cube around the bounds, as ours pads
    np.savez(src, depth=np.stack(depth), rgb=np.stack(rgb), K=cams.K.double().numpy(),
             w2c=cams.world_to_cam.double().numpy(), width=cams.width, height=cams.height, voxel=voxel,
             trunc=cfg.trunc * voxel, length=length, resolution=int(np.ceil(length / voxel)),
             origin=(lo + hi) / 2 - length / 2)
    t0 = time.perf_counter()
    subprocess.run([python, "-c", O3D_SCRIPT, str(src), str(dst)], check=True)
    elapsed = time.perf_counter() - t0
    d = np.load(dst)
    v, f, _, _ = keep_components(d["verts"], d["faces"].astype(np.int64), d["colors"], cfg.min_component)
    info = {"faces": len(f), "gt": ground_truth_chamfer(m.scene, v, f, cfg.chamfer_points)}
    return {"method": f"open3d {cfg_json}", "time_s": elapsed, **_summary(info)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("configs", nargs="*", default=["{}"], help="MeshConfig fields as JSON, one per variant")
    p.add_argument("--open3d-python", default=None, help="interpreter of a venv with open3d-cpu")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    from arcsem.runs import load_run

    m = load_run(args.run, colored=False)
    with tempfile.TemporaryDirectory() as tmp:
        for c in args.configs:
            print(json.dumps(ours(m, c, Path(tmp))), flush=True)
            if args.open3d_python:
                print(json.dumps(open3d(m, c, args.open3d_python, Path(tmp))), flush=True)


if __name__ == "__main__":
    sys.exit(main())
