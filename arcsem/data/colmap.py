"""COLMAP model reader (pycolmap; binary or text), with ``points3D`` as the initial point cloud.

Layout: ``<path>/sparse/0``, ``<path>/sparse`` or ``<path>`` holds the model (cameras, images,
points3D); images live in ``<path>/<images>`` and optional masks in ``<path>/<masks>`` (same
relative name as the image, any image extension). COLMAP's principal point already uses pixel
centres at ``+0.5``, like :mod:`arcsem.cameras`.

Camera models: PINHOLE and SIMPLE_PINHOLE are read as they are. SIMPLE_RADIAL, RADIAL, OPENCV and
FULL_OPENCV are undistorted with ``cv2.undistort`` (same K, same size) when ``undistort: true``,
and refused otherwise; every other model (fisheye, ...) is refused, naming the camera id and model.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError
from ..scene import Scene
from .build import ReaderOptions, ViewSpec, assemble_scene, check_intrinsics, undistorter
from .io import IMAGE_EXTS, dataset_root, resolve_file

__all__ = ["colmap_intrinsics", "find_colmap_model", "read_colmap"]

# model -> (fx, fy, cx, cy, [k1, k2, p1, p2, k3, k4, k5, k6]) from the params vector
_MODELS = {
    "SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2], []),
    "PINHOLE": lambda p: (p[0], p[1], p[2], p[3], []),
    "SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3], 0, 0, 0]),
    "RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4], 0, 0]),
    "OPENCV": lambda p: (p[0], p[1], p[2], p[3], list(p[4:8])),
    "FULL_OPENCV": lambda p: (p[0], p[1], p[2], p[3], list(p[4:12])),
}


def find_colmap_model(path: Path) -> Path:
    """The folder that holds ``cameras.bin|txt``: ``path/sparse/0``, ``path/sparse`` or ``path``."""
    if not path.exists():
        raise DataError(f"dataset path does not exist: {path}")
    for cand in (path / "sparse" / "0", path / "sparse", path):
        if (cand / "cameras.bin").is_file() or (cand / "cameras.txt").is_file():
            return cand
    raise DataError(f"{path}: no COLMAP model (cameras.bin/.txt in sparse/0, sparse or the folder itself)")


def colmap_intrinsics(camera, undistort: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """``K [3, 3]`` and OpenCV distortion coefficients (None if none) of a pycolmap camera."""
    model = camera.model.name if hasattr(camera.model, "name") else str(camera.model)
    params = np.asarray(camera.params, dtype=np.float64)
    if model not in _MODELS:
        raise DataError(f"COLMAP camera {camera.camera_id}: model {model} is not supported "
                        f"(supported: {', '.join(_MODELS)})")
    fx, fy, cx, cy, dist = _MODELS[model](params)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    check_intrinsics(K, int(camera.width), int(camera.height), "pinhole", f"COLMAP camera {camera.camera_id}",
                     ("focal length fx", "focal length fy", "principal point cx", "principal point cy"))
    if not any(float(d) != 0.0 for d in dist):
        return K, None
    if not undistort:
        raise DataError(f"COLMAP camera {camera.camera_id}: model {model} has lens distortion; "
                        "set dataset.undistort=true or run colmap image_undistorter first")
    return K, np.asarray(dist, dtype=np.float64)


def _pose(image) -> np.ndarray:
    rigid = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
    w2c = np.eye(4)
    w2c[:3, :4] = np.asarray(rigid.matrix())
    return w2c


def read_colmap(path: str | Path, opts: ReaderOptions | None = None, *, images: str = "images",
                masks: str | None = None, undistort: bool = True) -> Scene:
    """Read a COLMAP model and its images into a :class:`Scene` (see the module docstring)."""
    import pycolmap

    opts = opts or ReaderOptions()
    root = dataset_root(path)
    model_dir = find_colmap_model(root)
    ext = ".bin" if (model_dir / "cameras.bin").is_file() else ".txt"
    missing = [f"{n}{ext}" for n in ("cameras", "images", "points3D") if not (model_dir / f"{n}{ext}").is_file()]
    if missing:
        raise DataError(f"{model_dir}: COLMAP model incomplete, {', '.join(missing)} missing (a model is cameras, "
                        f"images and points3D{ext})")
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # noqa: BLE001 (pycolmap raises plain RuntimeError/ValueError for broken files)
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise DataError(f"{model_dir}: cannot read the COLMAP model (cameras{ext}, images{ext}, points3D{ext}): "
                        f"a file is truncated or corrupt (pycolmap: {first})") from None
    intr = {cid: colmap_intrinsics(cam, undistort) for cid, cam in rec.cameras.items()}
    views = []
    for _, img in sorted(rec.images.items(), key=lambda kv: kv[1].name):
        cam = rec.cameras[img.camera_id]
        K, dist = intr[img.camera_id]
        where = f"COLMAP image '{img.name}'"
        file = resolve_file(root / images, img.name, where)
        stem = str(Path(img.name).with_suffix(""))
        mask = resolve_file(root / masks, stem, f"{where} mask", IMAGE_EXTS) if masks else None
        views.append(ViewSpec(
            name=Path(img.name).stem, image=file, w2c=_pose(img), K=K, width=int(cam.width),
            height=int(cam.height), mask=mask, undistort=None if dist is None else undistorter(K, dist)))
    points = colors = None
    if rec.num_points3D() > 0:
        pts = list(rec.points3D.values())
        points = np.stack([p.xyz for p in pts]).astype(np.float32)
        colors = np.stack([p.color for p in pts]).astype(np.float32) / 255.0
    return assemble_scene(root, views, opts, points=points, point_colors=colors)
