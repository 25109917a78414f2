"""COLMAP model (pycolmap) of the synthetic pinhole cameras: cameras, images and 3-D points."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cameras import Cameras

__all__ = ["write_colmap"]


def write_colmap(folder: Path, cams: Cameras, names: list[str], pts: np.ndarray, cols: np.ndarray) -> Path:
    """Write ``cameras.bin, images.bin, points3D.bin`` (and pycolmap's rigs/frames) to ``folder``.

    One shared PINHOLE camera; image ``i + 1`` is ``images/<names[i]>.png`` with pose
    ``cam_from_world`` = the OpenCV world-to-camera of ``cams[i]``; points ``[P, 3]`` with uint8
    colours ``[P, 3]`` and empty tracks.
    """
    import pycolmap

    if cams.model != "pinhole":
        raise ValueError("COLMAP has no orthographic camera model")
    folder.mkdir(parents=True, exist_ok=True)
    K = cams.K[0].double().numpy()
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera(model="PINHOLE", width=cams.width, height=cams.height,
                          params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], camera_id=1)
    rec.add_camera_with_trivial_rig(cam)
    w2c = cams.world_to_cam.double().numpy()
    for i, name in enumerate(names):
        R, t = w2c[i, :3, :3], w2c[i, :3, 3]
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"images/{name}.png", camera_id=1, image_id=i + 1), pose)
    for x, c in zip(pts.astype(np.float64), cols.astype(np.uint8)):
        rec.add_point3D(x, pycolmap.Track(), c)
    rec.write_binary(str(folder))
    return folder
