"""The dataset folder of a calibrated series.

Layout: ``transforms.json`` (``camera_model: ORTHOGRAPHIC``, read by :mod:`arcsem.data.transforms`),
``images/<view>.png`` (cropped, at the input's bit depth), ``masks/<view>.png`` (255 = specimen),
``points3d.ply`` (the sparse points, grey), ``sparse/0/`` (a COLMAP model of far pinhole cameras with the
tracks, for tools that need one; images relative to ``images/``) and ``report/`` (:mod:`.report`).

Orthographic view ``i`` (``u = s_i P R_i X + t_i``) becomes ``K = [[s_i, 0, w/2], [0, s_i, h/2], [0, 0, 1]]``
and ``world_to_cam = [R_i | ((t_i - c) / s_i, D)]``: its camera plane lies ``D`` (twice the points' radius)
in front of the origin, so every point has positive depth. The far pinhole has the paper's focal length
(50,000 px at 3072 px width, scaled) at distance ``f / s_i``: the same pixels at the origin's depth.
"""
from __future__ import annotations

import numpy as np

from ..cameras import opengl_to_opencv
from ..data.ply import write_points
from ..files import write_json_atomic

__all__ = ["PAPER_FOCAL_PER_PX", "ortho_world_to_cam", "write_colmap_model", "write_dataset"]

PAPER_FOCAL_PER_PX = 50_000.0 / 3072  # the paper's RealityCapture focal length per pixel of image width


def ortho_world_to_cam(R: np.ndarray, t: np.ndarray, scale: np.ndarray, size: tuple[int, int], depth: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``world_to_cam [V, 4, 4]`` and ``K [V, 3, 3]`` of orthographic views (module docstring)."""
    w, h = size
    V = len(R)
    c = np.array([w / 2, h / 2])
    w2c = np.tile(np.eye(4), (V, 1, 1))
    w2c[:, :3, :3] = R
    w2c[:, :2, 3] = (t - c) / scale[:, None]
    w2c[:, 2, 3] = depth
    K = np.tile(np.eye(3), (V, 1, 1))
    K[:, 0, 0] = K[:, 1, 1] = scale
    K[:, 0, 2], K[:, 1, 2] = c
    return w2c, K


def _c2w_opengl(w2c: np.ndarray) -> np.ndarray:
    import torch

    c2w = np.linalg.inv(w2c)
    return opengl_to_opencv(torch.from_numpy(c2w)).numpy()  # the flip is its own inverse


def write_colmap_model(folder, names: list[str], R, t, scale, size, X, colors, obs) -> None:
    """``cameras/images/points3D.bin`` of far pinhole cameras with the tracks (module docstring)."""
    import pycolmap

    w, h = size
    focal = PAPER_FOCAL_PER_PX * w
    folder.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=w, height=h,
                                                    params=[focal, focal, w / 2, h / 2], camera_id=1))
    index_in_view = np.zeros(len(obs.vi), np.int64)
    for v in range(len(names)):
        sel = np.nonzero(obs.vi == v)[0]
        index_in_view[sel] = np.arange(len(sel))
        pts2d = [pycolmap.Point2D(obs.uv[k]) for k in sel]
        trans = np.r_[(t[v] - np.array([w / 2, h / 2])) / scale[v], focal / scale[v]]
        image = pycolmap.Image(name=f"{names[v]}.png", camera_id=1, image_id=v + 1, points2D=pts2d)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R[v]), trans))
    grey = np.clip(np.round(colors * 255), 0, 255).astype(np.uint8)
    order = np.argsort(obs.pj, kind="stable")
    bounds = np.searchsorted(obs.pj[order], np.arange(len(X) + 1))
    for j in range(len(X)):
        ks = order[bounds[j]:bounds[j + 1]]
        track = pycolmap.Track([pycolmap.TrackElement(int(obs.vi[k]) + 1, int(index_in_view[k])) for k in ks])
        rec.add_point3D(X[j], track, np.repeat(grey[j], 3))
    rec.write_binary(str(folder))


def write_dataset(out, names, images, masks, R, t, scale, X, colors, obs, *, size, splits, pixel_size_um,
                  aabb, extra: dict) -> None:
    """Write the dataset folder ``out`` (module docstring); ``images`` uint8/uint16 ``[h, w]`` (cropped)."""
    import cv2

    (out / "images").mkdir(parents=True, exist_ok=True)
    radius = float(np.linalg.norm(X, axis=1).max()) if len(X) else 1.0
    w2c, K = ortho_world_to_cam(R, t, scale, size, 2.0 * radius + 1e-6)
    c2w = _c2w_opengl(w2c)
    frames = []
    for i, name in enumerate(names):
        if not cv2.imwrite(str(out / "images" / f"{name}.png"), images[i]):
            raise OSError(f"cannot write {out / 'images' / f'{name}.png'}")
        frame = {"file_path": f"images/{name}.png", "transform_matrix": c2w[i].tolist(), "split": splits[i],
                 "fl_x": float(K[i, 0, 0]), "fl_y": float(K[i, 1, 1])}
        if masks is not None:
            (out / "masks").mkdir(exist_ok=True)
            cv2.imwrite(str(out / "masks" / f"{name}.png"), masks[i].astype(np.uint8) * 255)
            frame["mask_path"] = f"masks/{name}.png"
        frames.append({**frame, **extra.get("frames", [{}] * len(names))[i]})
    write_points(out / "points3d.ply", X, np.repeat(colors[:, None], 3, 1))
    write_colmap_model(out / "sparse" / "0", names, R, t, scale, size, X, colors, obs)
    meta = {"camera_model": "ORTHOGRAPHIC", "w": size[0], "h": size[1], "cx": size[0] / 2, "cy": size[1] / 2,
            "aabb": np.asarray(aabb).tolist(), "ply_file_path": "points3d.ply"}
    if pixel_size_um:
        meta["pixel_size_um"] = float(pixel_size_um)
    meta.update({k: v for k, v in extra.items() if k != "frames"})
    write_json_atomic(out / "transforms.json", {**meta, "frames": frames})
