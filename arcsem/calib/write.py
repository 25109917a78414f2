"""The dataset folder of a calibrated series.

Layout: ``transforms.json`` (``camera_model: ORTHOGRAPHIC``, read by :mod:`arcsem.data.transforms`),
``images/<view>.png`` (cropped, at the input's bit depth), ``masks/<view>.png`` (255 = specimen),
``points3d.ply`` (the sparse points, grey), ``sparse/0/`` (a COLMAP model of far pinhole cameras with the
tracks, for tools that need one; images relative to ``images/``) and ``report/`` (:mod:`.report`).

Orthographic view ``i`` (``u = s_i P R_i X + t_i``) becomes ``K = [[s_i, 0, w/2], [0, s_i, h/2], [0, 0, 1]]``
and ``world_to_cam = [R_i | ((t_i - c) / s_i, D)]``: its camera plane lies ``D`` (twice the points' radius)
in front of the origin, so every point has positive depth. Its COLMAP model is a far pinhole with the
paper's focal length (50,000 px at 3072 px width, scaled) at distance ``f / s_i``: the same pixels at the
origin's depth. Pinhole views (``--camera perspective``, :mod:`.perspective`) are written as they are:
``camera_model: PINHOLE`` with their focal length, and the same cameras in the COLMAP model.
"""
from __future__ import annotations

import numpy as np

from ..cameras import opengl_to_opencv
from ..files import write_json_atomic
from ..ply import write_points

__all__ = ["PAPER_FOCAL_PER_PX", "colmap_cameras", "ortho_world_to_cam", "write_colmap_model", "write_dataset"]

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


def colmap_cameras(views, size: tuple[int, int]) -> tuple[float, np.ndarray]:
    """The COLMAP model's pinhole cameras of ``views`` (module docstring): ``(focal px, translations [V, 3])``."""
    if hasattr(views, "focal"):
        return float(views.focal), views.T
    focal = PAPER_FOCAL_PER_PX * size[0]
    c = np.array(size, float) / 2
    return focal, np.concatenate([(views.t - c) / views.scale[:, None], (focal / views.scale)[:, None]], 1)


def write_colmap_model(folder, names: list[str], views, size, X, colors, obs) -> None:
    """``cameras/images/points3D.bin`` of pinhole cameras (:func:`colmap_cameras`) with the tracks."""
    import pycolmap

    w, h = size
    focal, T = colmap_cameras(views, size)
    folder.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=w, height=h,
                                                    params=[focal, focal, w / 2, h / 2], camera_id=1))
    index_in_view = np.zeros(len(obs.vi), np.int64)
    for v in range(len(names)):
        sel = np.nonzero(obs.vi == v)[0]
        index_in_view[sel] = np.arange(len(sel))
        pts2d = [pycolmap.Point2D(obs.uv[k]) for k in sel]
        image = pycolmap.Image(name=f"{names[v]}.png", camera_id=1, image_id=v + 1, points2D=pts2d)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(views.R[v]), T[v]))
    grey = np.clip(np.round(colors * 255), 0, 255).astype(np.uint8)
    order = np.argsort(obs.pj, kind="stable")
    bounds = np.searchsorted(obs.pj[order], np.arange(len(X) + 1))
    for j in range(len(X)):
        ks = order[bounds[j]:bounds[j + 1]]
        track = pycolmap.Track([pycolmap.TrackElement(int(obs.vi[k]) + 1, int(index_in_view[k])) for k in ks])
        rec.add_point3D(X[j], track, np.repeat(grey[j], 3))
    rec.write_binary(str(folder))


def _world_to_cam(views, X: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, str]:
    """``world_to_cam [V, 4, 4]``, ``K [V, 3, 3]`` and the ``camera_model`` of orthographic or pinhole views."""
    if hasattr(views, "focal"):
        V = len(views)
        w2c = np.tile(np.eye(4), (V, 1, 1))
        w2c[:, :3, :3], w2c[:, :3, 3] = views.R, views.T
        K = np.tile(np.eye(3), (V, 1, 1))
        K[:, 0, 0] = K[:, 1, 1] = views.focal
        K[:, 0, 2], K[:, 1, 2] = views.centre
        return w2c, K, "PINHOLE"
    radius = float(np.linalg.norm(X, axis=1).max()) if len(X) else 1.0
    return (*ortho_world_to_cam(views.R, views.t, views.scale, size, 2.0 * radius + 1e-6), "ORTHOGRAPHIC")


def write_dataset(out, names, images, masks, views, X, colors, obs, *, size, splits, pixel_size_um,
                  aabb, extra: dict, dense=(None, None)) -> None:
    """Write the dataset folder ``out`` (module docstring) of orthographic or pinhole ``views``; ``images``
    uint8/uint16 ``[h, w]`` (cropped); ``dense``: ``(points [P, 3], grey [P])`` of the dense start or None,
    written to ``points3d.ply`` after the adjustment's points ``X`` (the COLMAP model keeps ``X``'s tracks)."""
    import cv2

    (out / "images").mkdir(parents=True, exist_ok=True)
    if dense[0] is not None and len(dense[0]):
        every, every_grey = np.concatenate([X, dense[0]]), np.concatenate([colors, dense[1]])
    else:
        every, every_grey = X, colors
    w2c, K, model = _world_to_cam(views, every, size)
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
    write_points(out / "points3d.ply", every, np.repeat(every_grey[:, None], 3, 1))
    write_colmap_model(out / "sparse" / "0", names, views, size, X, colors, obs)
    meta = {"camera_model": model, "w": size[0], "h": size[1], "cx": float(K[0, 0, 2]), "cy": float(K[0, 1, 2]),
            "aabb": np.asarray(aabb).tolist(), "ply_file_path": "points3d.ply"}
    if pixel_size_um:
        meta["pixel_size_um"] = float(pixel_size_um)
    meta.update({k: v for k, v in extra.items() if k != "frames"})
    write_json_atomic(out / "transforms.json", {**meta, "frames": frames})
