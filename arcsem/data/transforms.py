"""NeRF / instant-ngp / torch-ngp ``transforms.json`` reader (the layout the ArCSEM authors used).

Schema (``*`` marks arcsem extensions); intrinsics may sit at the top level or in a frame:

* ``fl_x, fl_y, cx, cy, w, h`` or ``camera_angle_x`` (and ``camera_angle_y``) (NeRF); ``w, h``
  default to the image size, ``cx, cy`` to the image centre, ``fl_y`` to ``fl_x``;
* ``*camera_model``: ``PINHOLE`` (default; ``SIMPLE_PINHOLE`` and ``OPENCV``) or ``ORTHOGRAPHIC`` (``fl_x`` =
  pixels per world unit); ``k1, k2, k3, p1, p2`` (instant-ngp's, OpenCV's model): the images are undistorted as read
  (``dataset.undistort=true``, the default; the same ``K``), ``k4`` (fisheye) is refused;
* ``*aabb`` ``[[min], [max]]`` scene bounds (the specimen's: the Gaussians' length scale); ``content_aabb``: the
  box of all the views show, substrate and debris included (the Plenoxels grid spans it); ``ply_file_path``: initial point cloud;
  ``*pixel_size_um``: the images' pixel size in micrometres (SEM metadata) at ``w x h``, which
  gives lengths in micrometres (``Scene.micrometres_per_unit``: ``fl_x x pixel_size_um``, divided by
  the camera distance to the scene centre for pinhole cameras);
  ``*reference_sets`` ``{"five": [view names], ...}``;
* frames: ``file_path`` (extension optional, relative to the json), ``transform_matrix``
  (camera-to-world, OpenGL axes), optional ``mask_path``, ``*split`` (train/test),
  ``*depth_path`` (.npy z-depth, 0 = background), ``*normal_path`` (.npy ``[H, W, 3]``),
  ``*color_path``, ``*clean_path``, ``*reference_path`` (artist colour image of this view).

NeRF-synthetic folders with ``transforms_train.json`` / ``transforms_test.json`` are read too
(each file gives the split of its frames).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from ..cameras import opengl_to_opencv
from ..errors import DataError
from ..scene import Scene
from .build import ReaderOptions, ViewSpec, assemble_scene, check_intrinsics, check_rotation, undistorter
from .headers import check_declared_size, image_header
from .io import dataset_root, read_image, read_ply, resolve_file

__all__ = ["find_transforms_files", "frame_views", "load_json_file", "read_transforms"]

MODELS = {"PINHOLE": "pinhole", "SIMPLE_PINHOLE": "pinhole", "OPENCV": "pinhole", "ORTHOGRAPHIC": "orthographic"}
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", "camera_model",
                  *DISTORTION_KEYS)


def find_transforms_files(path: Path) -> list[tuple[Path, str | None]]:
    """``[(json file, split or None)]`` for a json file or a folder (transforms.json or _train/_test)."""
    if not path.exists():
        raise DataError(f"dataset path does not exist: {path}")
    if path.is_file():
        return [(path, None)]
    if (path / "transforms.json").is_file():
        return [(path / "transforms.json", None)]
    pairs = [(path / f"transforms_{s}.json", s) for s in ("train", "test")]
    if pairs[0][0].is_file():
        return [(p, s) for p, s in pairs if p.is_file()]
    raise DataError(f"{path}: no transforms.json (or transforms_train.json) in this folder")


def load_json_file(path: Path) -> object:
    """A JSON file as Python objects; DataError naming the file when it is not UTF-8 (a BOM is allowed), not
    JSON, or nested too deeply for the parser (a crafted file)."""
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
                        "save the file as UTF-8") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise DataError(f"{path}: the JSON is nested too deeply to read (thousands of levels of [ or {{)") from None


def _load_json(path: Path) -> dict:
    data = load_json_file(path)
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise DataError(f"{path}: expected an object with a 'frames' list")
    return data


def _number(p: dict, key: str, where: str, positive: bool = False) -> float:
    """``p[key]`` as a finite float (DataError naming the key otherwise); ``positive``: also > 0."""
    value = p[key]
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (positive and value <= 0):
        need = "a positive number" if positive else "a finite number"
        raise DataError(f"{where}: '{key}' must be {need}, got {value!r}")
    return float(value)


def _distortion(p: dict, model: str, undistort: bool, where: str) -> np.ndarray | None:
    """OpenCV ``[k1, k2, p1, p2, k3]`` of a pinhole frame (instant-ngp's keys, colmap2nerf's OPENCV camera), None
    without distortion (absent, 0 or null); DataError for ``k4`` (fisheye), an orthographic camera, or
    ``dataset.undistort=false``."""
    given = [k for k in DISTORTION_KEYS if p.get(k) is not None and _number(p, k, where) != 0.0]  # null: none
    if not given:
        return None
    if "k4" in given or model != "pinhole":
        raise DataError(f"{where}: lens distortion ({', '.join(given)}) of a {'fisheye' if 'k4' in given else model} "
                        "camera is not supported; undistort the images first")
    if not undistort:
        raise DataError(f"{where}: lens distortion ({', '.join(given)}); set dataset.undistort=true (the images are "
                        "then undistorted as read) or undistort the images first")
    return np.array([float(p.get(k) or 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])


def _intrinsics(p: dict, img_path: Path, where: str) -> tuple[np.ndarray, int, int, str]:
    """``K [3,3]``, w, h and model from merged top-level/frame keys ``p``."""
    name = str(p.get("camera_model", "PINHOLE")).upper()
    if name not in MODELS:
        raise DataError(f"{where}: unknown camera_model '{p.get('camera_model')}'; "
                        f"expected one of {', '.join(MODELS)}")
    model = MODELS[name]
    if "w" in p and "h" in p:
        w, h = _pixels(p, "w", where), _pixels(p, "h", where)
    else:  # the header's size; the pixels are decoded only where the header cannot be parsed
        wh = image_header(img_path)
        check_declared_size(img_path, wh)
        w, h = wh or read_image(img_path)[0].shape[1::-1]
    if "fl_x" in p:
        fx = _number(p, "fl_x", where, True)
    elif "camera_angle_x" in p and model == "pinhole":
        fx = 0.5 * w / math.tan(0.5 * _angle(p, "camera_angle_x", where))
    else:
        raise DataError(f"{where}: no focal length (fl_x or camera_angle_x)")
    if "fl_y" in p:
        fy = _number(p, "fl_y", where, True)
    elif "camera_angle_y" in p and model == "pinhole":
        fy = 0.5 * h / math.tan(0.5 * _angle(p, "camera_angle_y", where))
    else:
        fy = fx
    cx = _number(p, "cx", where) if "cx" in p else w / 2
    cy = _number(p, "cy", where) if "cy" in p else h / 2
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    check_intrinsics(K, w, h, model, where)
    return K, w, h, model


def _pixels(p: dict, key: str, where: str) -> int:
    """An image side in pixels: a whole number from 1 to 10^6."""
    value = _number(p, key, where, True)
    if value != int(value) or value > 1e6:
        raise DataError(f"{where}: '{key}' must be a whole number of pixels (1 to 1000000), got {p[key]!r}")
    return int(value)


def _angle(p: dict, key: str, where: str) -> float:
    """A field of view in radians, in (0, pi)."""
    a = _number(p, key, where, True)
    if a >= math.pi:
        raise DataError(f"{where}: '{key}' must be an angle in radians between 0 and pi, got {a}")
    return a


def _pose(frame: dict, where: str) -> np.ndarray:
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (KeyError, ValueError, TypeError):
        raise DataError(f"{where}: missing or malformed 'transform_matrix'") from None
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0, 0, 0, 1]])
    if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
        raise DataError(f"{where}: 'transform_matrix' must be a finite 4x4 (or 3x4) matrix")
    if np.abs(c2w[:3, 3]).max() > MAX_POSITION:
        raise DataError(f"{where}: 'transform_matrix' puts the camera at {c2w[:3, 3].tolist()}, over "
                        f"{MAX_POSITION:g} scene units from the origin")
    check_rotation(c2w[:3, :3], f"{where}: 'transform_matrix'")
    c2w_cv = opengl_to_opencv(torch.from_numpy(c2w)).numpy()
    return np.linalg.inv(c2w_cv)


MAX_POSITION = 1e12
"""Farthest camera position from the origin, in scene units (float32 cameras and bounds overflow beyond)."""

OPTIONAL = ("mask", "depth", "normal", "color", "clean", "reference")  # frame keys <name>_path


def _optional_file(base: Path, frame: dict, key: str, where: str) -> Path | None:
    if not frame.get(key):
        return None
    return resolve_file(base, str(frame[key]), f"{where} {key}", (".npy", ".png", ".tif", ".tiff"))


def frame_views(path: Path, data: dict, split: str | None, undistort: bool = True) -> list[ViewSpec]:
    """:class:`ViewSpec` of every frame of one parsed transforms file (``undistort``: lens distortion is undone as
    the images are read, else refused)."""
    base, top = path.parent, {k: data[k] for k in INTRINSIC_KEYS if k in data}
    views = []
    for i, frame in enumerate(data["frames"]):
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise DataError(f"{path}: frame {i} has no 'file_path'")
        where = f"{path}: frame {i} ('{frame['file_path']}')"
        image = resolve_file(base, str(frame["file_path"]), where)
        keys = {**top, **{k: frame[k] for k in INTRINSIC_KEYS if k in frame}}
        K, w, h, model = _intrinsics(keys, image, where)
        dist = _distortion(keys, model, undistort, where)
        views.append(ViewSpec(
            name=image.stem, image=image, w2c=_pose(frame, where), K=K, width=w, height=h, model=model,
            split=frame.get("split", split), undistort=None if dist is None else undistorter(K, dist),
            **{k: _optional_file(base, frame, f"{k}_path", where) for k in OPTIONAL}))
    return views


def read_transforms(path: str | Path, opts: ReaderOptions | None = None, *, undistort: bool = True) -> Scene:
    """Read a transforms.json file or folder into a :class:`Scene` (see the module docstring); ``undistort``: lens
    distortion (``k1, k2, k3, p1, p2``) undone as the images are read (``cv2.undistort``, the same ``K``), else
    refused."""
    opts = opts or ReaderOptions()
    files = find_transforms_files(dataset_root(path))
    views, first = [], None
    for file, split in files:
        data = _load_json(file)
        first = first or (file, data)
        views += frame_views(file, data, split, undistort)
    file, data = first
    points = colors = None
    if data.get("ply_file_path"):
        points, colors = read_ply(resolve_file(file.parent, data["ply_file_path"], f"{file}: ply_file_path", ()))
    sets = data.get("reference_sets") or {}
    if not isinstance(sets, dict) or not all(isinstance(v, list) for v in sets.values()):
        raise DataError(f"{file}: 'reference_sets' must map names to lists of view names")
    scene = assemble_scene(file.parent, views, opts, bounds=data.get("aabb"), points=points,
                           point_colors=colors, reference_sets=sets, specimen_size=_specimen_size(file, data),
                           content_bounds=data.get("content_aabb"))
    scene.micrometres_per_unit = _micrometres_per_unit(file, data, scene, opts.downscale)
    return scene


def _micrometres_per_unit(file: Path, data: dict, scene: Scene, downscale: float) -> float | None:
    """Micrometres per world unit from ``pixel_size_um`` (None without it); see the module docstring."""
    size = data.get("pixel_size_um")
    if size is None:
        return None
    if not _positive_finite(size):
        raise DataError(f"{file}: 'pixel_size_um' must be a positive finite number (micrometres), got {size!r}")
    cams = scene.train.cameras
    px_per_unit = cams.K[:, 0, 0].double() * float(downscale)  # at the json's resolution
    if not cams.is_ortho:
        centre = scene.bounds.double().mean(0)
        px_per_unit = px_per_unit / cams.to(dtype=torch.float64).to_camera(centre[None])[:, 0, 2].abs()
    return float(px_per_unit.median()) * float(size)


def _specimen_size(file: Path, data: dict) -> float | None:
    """``specimen_size`` (or the synthetic generator's ``synthetic.grain_size``): a positive length, or None."""
    size = data.get("specimen_size", (data.get("synthetic") or {}).get("grain_size"))
    if size is None:
        return None
    if not _positive_finite(size):
        raise DataError(f"{file}: 'specimen_size' must be a positive finite number, got {size!r}")
    return float(size)


def _positive_finite(value: object) -> bool:
    """A JSON number (not a boolean) that is finite and > 0 (``Infinity``, ``NaN``, 0 and negatives are not)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
