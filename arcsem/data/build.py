"""Reader-independent assembly: view selection, train/test split, image loading, bounds.

Readers (transforms.json, COLMAP) turn their files into :class:`ViewSpec` records (a camera and
file paths, no pixels); :func:`assemble_scene` selects views, splits them, reads and downscales the
images and returns the :class:`~arcsem.scene.Scene`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..cameras import Cameras
from ..configs import ReaderOptions
from ..errors import DataError
from ..names import view_names
from ..registry import plain, validate_config
from ..scene import Scene, Split
from .headers import check_declared_size, check_image_budget, image_header
from .io import (
    grey_if_equal_channels,
    luminance,
    read_array,
    read_image,
    read_image_levels,
    read_mask,
    resize,
)

__all__ = [
    "ReaderOptions",
    "ViewSpec",
    "assemble_scene",
    "bounds_from_cameras",
    "bounds_from_points",
    "check_intrinsics",
    "check_rotation",
    "reader_options",
    "select_views",
    "undistorter",
]



def check_rotation(R: np.ndarray, where: str, tol: float = 1e-3) -> None:
    """DataError unless ``R [3, 3]`` is a rotation (orthonormal, determinant +1, to ``tol``): a camera pose
    with a singular or scaled rotation part (a broken export) cannot be inverted or rendered."""
    R = np.asarray(R, dtype=np.float64)
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if not np.isfinite(err) or err > tol or det < 0:
        what = "singular" if abs(det) < 1e-9 else ("a reflection" if det < 0 else "not orthonormal")
        raise DataError(f"{where}: the rotation part is {what} (|R^T R - I| = {err:.3g}, det = {det:.3g}); "
                        "a camera pose must be a rigid transform")


MAX_INTRINSIC = 1e12
"""Largest focal length or principal point (pixels) arcsem accepts: the float32 renderers square focal lengths."""
MAX_PINHOLE_FOCAL_WIDTHS = 1e6
"""A pinhole focal length above this many image widths is a field of view under a microradian: orthographic."""


def check_intrinsics(K: np.ndarray, width: int, height: int, model: str, where: str,
                     keys: tuple[str, str, str, str] = ("fl_x", "fl_y", "cx", "cy")) -> None:
    """DataError naming the key (``keys``: the file's names of fx, fy, cx, cy) when ``K [3, 3]`` holds a number the
    renderers cannot use: not finite, above :data:`MAX_INTRINSIC`, a pinhole focal length above
    :data:`MAX_PINHOLE_FOCAL_WIDTHS` image widths or under a thousandth of one, or a principal point 100 image sizes
    away from the image."""
    values = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    for key, value, size in zip(keys, values, (width, height, width, height)):
        v = float(value)
        if not np.isfinite(v) or abs(v) > MAX_INTRINSIC:
            raise DataError(f"{where}: '{key}' = {v:g} is out of range (at most {MAX_INTRINSIC:g} pixels)")
        if key in keys[:2] and model == "pinhole" and v > MAX_PINHOLE_FOCAL_WIDTHS * size:
            raise DataError(f"{where}: '{key}' = {v:g} px is over {MAX_PINHOLE_FOCAL_WIDTHS:g} image widths (a field "
                            "of view under a microradian); for such a camera use camera_model ORTHOGRAPHIC")
        if key in keys[:2] and model == "pinhole" and v < 1e-3 * size:
            raise DataError(f"{where}: '{key}' = {v:g} px is under a thousandth of the image size {size} (a field of "
                            "view over 179.8 degrees): not a pinhole camera")
        if key in keys[2:] and abs(v) > 100 * size:
            raise DataError(f"{where}: '{key}' = {v:g} px puts the principal point over 100 image sizes "
                            f"away from the {width}x{height} image")


@dataclass
class ViewSpec:
    """One view before its pixels are read. ``w2c`` ``[4, 4]`` (OpenCV axes), ``K`` ``[3, 3]``.

    ``undistort`` is an optional function applied to every image read for this view (COLMAP).
    """

    name: str
    image: Path
    w2c: np.ndarray
    K: np.ndarray
    width: int
    height: int
    model: str = "pinhole"
    split: str | None = None
    mask: Path | None = None
    depth: Path | None = None
    normal: Path | None = None
    color: Path | None = None
    clean: Path | None = None
    reference: Path | None = None
    undistort: Callable[[np.ndarray], np.ndarray] | None = field(default=None, repr=False)


def undistorter(K: np.ndarray, dist: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The :attr:`ViewSpec.undistort` of a pinhole camera ``K [3, 3]`` with OpenCV distortion ``dist``
    (``[k1, k2, p1, p2[, k3]]``): ``cv2.undistort`` to the same ``K`` and size, for every image of the view."""
    def undistort(arr: np.ndarray) -> np.ndarray:
        import cv2

        out = cv2.undistort(np.ascontiguousarray(arr, dtype=np.float32), K, dist, None, K)
        return out.reshape(arr.shape)

    return undistort


def reader_options(cfg: Any) -> ReaderOptions:
    """Validated :class:`ReaderOptions` from a dataset config (a DictConfig or a dict)."""
    get = (lambda k, d: cfg.get(k, d)) if hasattr(cfg, "get") else (lambda k, d: getattr(cfg, k, d))
    values = {k: get(k, None) for k in ("downscale", "split", "test_every", "max_views", "holdout", "grey")}
    if values["holdout"] is not None:
        values["holdout"] = [str(v) for v in plain(values["holdout"])] if not isinstance(values["holdout"], str) \
            else [values["holdout"]]
    if values["downscale"] is None:  # `downscale: null` means no downscaling (0 is refused, not read as 1)
        values["downscale"] = 1.0
    return validate_config(ReaderOptions, {k: v for k, v in values.items() if v is not None or k == "max_views"},
                           where="dataset")


def select_views(views: list[ViewSpec], opts: ReaderOptions) -> tuple[list[ViewSpec], list[ViewSpec]]:
    """Apply ``max_views`` (evenly spaced) then the split; returns ``(train, test)``."""
    names = [v.name for v in views]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DataError(f"duplicate view names (file stems): {', '.join(dup)}")
    if opts.max_views is not None and len(views) > int(opts.max_views):
        keep = np.unique(np.round(np.linspace(0, len(views) - 1, int(opts.max_views))).astype(int))
        views = [views[i] for i in keep]
    if opts.split == "every_k":
        return ([v for i, v in enumerate(views) if i % opts.test_every != 0],
                [v for i, v in enumerate(views) if i % opts.test_every == 0])
    if opts.split == "holdout":
        return _holdout(views, opts.holdout)
    if opts.split == "auto" and any(v.split is not None for v in views):
        bad = [v.name for v in views if v.split not in (None, "train", "test")]
        if bad:
            raise DataError(f"view '{bad[0]}': split must be 'train' or 'test'")
        return [v for v in views if v.split != "test"], [v for v in views if v.split == "test"]
    return list(views), []


def _holdout(views: list[ViewSpec], held: list[str]) -> tuple[list[ViewSpec], list[ViewSpec]]:
    """``split=holdout``: the views named in ``held`` are the test views, every other view trains."""
    names = [v.name for v in views]
    unknown = [h for h in held if h not in names]
    if not held or unknown:
        why = f"unknown view(s) {', '.join(unknown)}" if unknown else "no view named"
        raise DataError(f"dataset.holdout: {why}; the views are {', '.join(names[:12])}"
                        + (" ..." if len(names) > 12 else ""))
    return [v for v in views if v.name not in held], [v for v in views if v.name in held]


def _read_view(v: ViewSpec, size: tuple[int, int], grey: bool = False) -> dict[str, np.ndarray | None]:
    """Read every file of one view at the camera's size, undistort, and resize to ``size`` (w, h).

    An alpha channel that is 0 everywhere (an exporter that never set it) is ignored: the colour channels are
    the image and alpha gives no mask (``out["notes"]`` says ``alpha0``). An RGB image of grey content is read as
    grey (:func:`~arcsem.data.io.grey_if_equal_channels`); one of colour content is kept and noted ``colour``, or
    with ``grey`` (``dataset.grey=true``) read as its luminance, its colour becoming the view's ``color`` (where
    the view has no colour file)."""
    img, alpha, lv = read_image_levels(v.image)
    notes = []
    if alpha is not None and not alpha.any():
        alpha = None
        notes.append("alpha0")
    img, coloured = grey_if_equal_channels(img)
    own_colour = None
    if grey:
        own_colour, img = img, luminance(img)
        notes += ["grey_of_colour"] if coloured else []
    elif coloured:
        notes.append("colour")
    if img.shape[:2] != (v.height, v.width):
        raise DataError(f"view '{v.name}': image {v.image} is {img.shape[1]}x{img.shape[0]} "
                        f"but its camera is {v.width}x{v.height}")

    def fit(arr: np.ndarray, path: Path, nearest: bool = False) -> np.ndarray:
        if arr.shape[:2] != (v.height, v.width):
            raise DataError(f"view '{v.name}': {path} is {arr.shape[1]}x{arr.shape[0]}, "
                            f"expected {v.width}x{v.height}")
        if v.undistort is not None:
            arr = v.undistort(arr)
        return resize(arr, size, nearest)

    out: dict[str, np.ndarray | list | None] = {"notes": notes, "levels": lv.describe()}
    if alpha is not None:  # RGBA -> RGB over a black background; alpha is the mask unless one is given
        img = img * alpha[..., None]
        own_colour = None if own_colour is None else own_colour * alpha[..., None]
    out["image"] = fit(img, v.image)
    mask = read_mask(v.mask) if v.mask is not None else (alpha > 0.5 if alpha is not None else None)
    out["mask"] = None if mask is None else fit(mask.astype(np.float32), v.mask or v.image) > 0.5
    hw = (v.height, v.width)
    out["depth"] = None if v.depth is None else fit(read_array(v.depth, hw, None, "depth"), v.depth, True)
    out["normal"] = None if v.normal is None else fit(read_array(v.normal, hw, 3, "normals"), v.normal, True)
    for key in ("color", "clean", "reference"):
        path = getattr(v, key)
        out[key] = None if path is None else fit(read_image(path)[0], path)
    if out["color"] is None and own_colour is not None:
        out["color"] = fit(own_colour, v.image)
    return out


def _stack(items: list[np.ndarray | None], name: str, views: list[ViewSpec]) -> torch.Tensor | None:
    """Stack per-view arrays; all-or-none (a view lacking a file present elsewhere is an error)."""
    have = [x is not None for x in items]
    if not any(have):
        return None
    if not all(have):
        missing = views[have.index(False)].name
        raise DataError(f"view '{missing}' has no {name} while other views do")
    return torch.from_numpy(np.stack(items))


def _load_split(views: list[ViewSpec], size: tuple[int, int], factor: float, train: bool,
                model: str, grey: bool = False) -> tuple[Split, dict[str, torch.Tensor], dict[str, list[Path]]]:
    """The split of ``views`` at ``size``, its reference images by view name, and the image files of each
    reading note of :func:`_read_view` (``{"alpha0": [...], "colour": [...], "levels <range>": [...]}``)."""
    data = [_read_view(v, size, grey) for v in views]
    notes: dict[str, list[Path]] = {}
    for v, d in zip(views, data):
        for note in [*d["notes"], f"levels {d['levels']}"]:
            notes.setdefault(note, []).append(v.image)
    w, h = (views[0].width, views[0].height) if views else size
    w2c = torch.from_numpy(np.stack([v.w2c for v in views])).float() if views else torch.zeros(0, 4, 4)
    K = torch.from_numpy(np.stack([v.K for v in views])).float() if views else torch.zeros(0, 3, 3)
    ids = torch.arange(len(views)) if train else torch.full((len(views),), -1, dtype=torch.long)
    cams = Cameras(w2c, K, w, h, model, image_ids=ids)
    if factor != 1.0:
        cams = cams.scaled(1.0 / factor)
    col = lambda k: _stack([d[k] for d in data], k, views)
    images = col("image") if views else torch.zeros(0, size[1], size[0], 3)
    split = Split([v.name for v in views], cams, images, masks=col("mask"), depths=col("depth"),
                  normals=col("normal"), colors=col("color"), clean=col("clean"),
                  files=[str(v.image) for v in views])
    refs = {v.name: torch.from_numpy(d["reference"]) for v, d in zip(views, data) if d["reference"] is not None}
    return split, refs, notes


def _reading_warnings(notes: dict[str, list[Path]]) -> list[str]:
    """One warning per reading note of :func:`_read_view`, naming the first file and how many there are."""
    text = {"alpha0": "an alpha channel that is 0 everywhere: the alpha is ignored (the colour channels are the "
                      "image, no masks from alpha)",
            "colour": "colour content (not grey): stage 1 fits it as colour, although SEM views are grey; convert "
                      "the images to grey if they are SEM images"}
    out = []
    for note, files in notes.items():
        if note.startswith("levels ") or note == "grey_of_colour":
            continue
        more = f" and {len(files) - 1} more" if len(files) > 1 else ""
        out.append(f"{files[0]}{more}: {text[note]}")
    return out


def intensity_ranges(notes: dict[str, list[Path]]) -> list[dict]:
    """The intensity ranges the views' files were read over (:func:`~arcsem.data.io.read_image_levels`), one
    entry per distinct range: ``{"levels": "lo..hi (source)", "views": count, "first": file}``."""
    return [{"levels": note.removeprefix("levels "), "views": len(files), "first": str(files[0])}
            for note, files in notes.items() if note.startswith("levels ")]


def _common_size(views: list[ViewSpec]) -> tuple[int, int, str]:
    first = views[0]
    for v in views[1:]:
        if (v.width, v.height) != (first.width, first.height):
            raise DataError(f"view '{v.name}' ({v.image}) is {v.width}x{v.height} but '{first.name}' is "
                            f"{first.width}x{first.height}; all views must share one size")
        if v.model != first.model:
            raise DataError(f"view '{v.name}' uses a {v.model} camera but '{first.name}' a {first.model} one")
    return first.width, first.height, first.model


def bounds_from_points(points: np.ndarray, pad: float = 0.05) -> torch.Tensor:
    """``[2, 3]`` box around the 0.5-99.5 percentiles of ``points [P, 3]``, padded by ``pad`` x size."""
    lo, hi = np.percentile(points, 0.5, axis=0), np.percentile(points, 99.5, axis=0)
    d = (hi - lo) * pad
    return torch.tensor(np.stack([lo - d, hi + d]), dtype=torch.float32)


def bounds_from_cameras(cams: Cameras) -> torch.Tensor:
    """``[2, 3]`` box from the camera frusta: the point nearest all optical axes (least squares),
    with a half-size equal to the largest image footprint half-diagonal at that point."""
    c, d = cams.centers.double(), cams.forward.double()
    proj = torch.eye(3, dtype=c.dtype) - d[:, :, None] * d[:, None, :]  # [C, 3, 3] onto the normal plane
    A, b = proj.sum(0), (proj @ c[..., None]).sum(0)[:, 0]
    center = torch.linalg.lstsq(A, b).solution if len(cams) > 1 else c[0] + d[0]
    fx, fy = cams.K[:, 0, 0].double(), cams.K[:, 1, 1].double()
    half = torch.sqrt((cams.width / (2 * fx)) ** 2 + (cams.height / (2 * fy)) ** 2)
    if not cams.is_ortho:
        half = half * ((center - c) * d).sum(-1).abs()
    r = float(half.max())
    return torch.stack([center - r, center + r]).float()


def assemble_scene(root: Path, views: list[ViewSpec], opts: ReaderOptions, *, bounds: Any = None,
                   points: np.ndarray | None = None, point_colors: np.ndarray | None = None,
                   reference_sets: dict[str, list[str]] | None = None, specimen_size: float | None = None,
                   content_bounds: Any = None) -> Scene:
    """Select, split and read ``views``; bounds from ``bounds``, else the points, else the frusta;
    ``content_bounds``: the box of all the views show, where the dataset gives it (``content_aabb``)."""
    if not views:
        raise DataError(f"{root}: the dataset has no views")
    seen: dict[Path, int] = {}
    for i, v in enumerate(views):
        if v.image in seen:
            raise DataError(f"{root}: views {seen[v.image]} and {i} both read {v.image}; each view needs its own image")
        seen[v.image] = i
    for v, name in zip(views, view_names([v.image for v in views])):
        v.name = name
    w, h, model = _common_size(views)
    train_v, test_v = select_views(views, opts)
    if not train_v:
        raise DataError(f"{root}: no training views after the split (split={opts.split})")
    size = (round(w / opts.downscale), round(h / opts.downscale))
    _check_headers(train_v + test_v, opts.downscale)
    train, refs, notes = _load_split(train_v, size, opts.downscale, True, model, opts.grey)
    test, test_refs, test_notes = _load_split(test_v, size, opts.downscale, False, model, opts.grey)
    refs.update(test_refs)
    for note, files in test_notes.items():
        notes.setdefault(note, []).extend(files)
    warnings = _reading_warnings(notes)
    if opts.grey and "grey_of_colour" not in notes and all(v.color is None for v in train_v + test_v):
        train.colors = test.colors = None  # grey images' "colour" would score stage 2 against grey
        warnings.append(f"{root}: dataset.grey=true but every view is grey already: no colour ground truth from them")
    known, all_names = set(train.names) | set(test.names), {v.name for v in views}
    for set_name, names in (reference_sets or {}).items():
        bad = [n for n in names if n not in all_names]
        if bad:
            raise DataError(f"{root}: reference set '{set_name}' names unknown view(s) {', '.join(bad)}")
    sets = {k: [n for n in v if n in known] for k, v in (reference_sets or {}).items()}
    box = _box(root, bounds, "aabb") if bounds is not None else None
    content = _box(root, content_bounds, "content_aabb") if content_bounds is not None else None
    source = "given"
    if bounds is None and points is not None and len(points) > 0:
        box, source = bounds_from_points(points), "points"
    elif bounds is None:
        box, source = bounds_from_cameras(train.cameras), "cameras"
    to_t = lambda a: None if a is None else torch.as_tensor(np.asarray(a, dtype=np.float32))
    return Scene(str(root), train, test, box, points=to_t(points), point_colors=to_t(point_colors),
                 references=refs, reference_sets=sets, specimen_size=specimen_size, bounds_source=source,
                 warnings=warnings, intensity=intensity_ranges(notes), content_bounds=content)


def _box(root: Path, bounds: Any, key: str) -> torch.Tensor:
    """A dataset's box ``[2, 3]`` (``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``) under ``key``, checked."""
    try:
        box = torch.as_tensor(np.asarray(bounds, dtype=np.float32)).reshape(2, 3)
    except (ValueError, TypeError, RuntimeError):
        raise DataError(f"{root}: '{key}' must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {bounds}") from None
    if not torch.isfinite(box).all():
        raise DataError(f"{root}: '{key}' must hold finite numbers, got {box.tolist()}")
    if not (box[1] > box[0]).all():
        raise DataError(f"{root}: '{key}' max {box[1].tolist()} must exceed min {box[0].tolist()}")
    return box


def _check_headers(views: list[ViewSpec], downscale: float) -> None:
    """Before any pixel is decoded: every image's header size matches its camera, none is a decompression bomb,
    and reading them all fits in memory (:func:`~arcsem.data.headers.check_image_budget`)."""
    sizes = []
    for v in views:
        wh = image_header(v.image)
        check_declared_size(v.image, wh)
        turned = v.image.suffix.lower() in (".tif", ".tiff")  # the Orientation tag may swap width and height
        if wh is not None and wh != (v.width, v.height) and not turned:
            raise DataError(f"view '{v.name}': image {v.image} is {wh[0]}x{wh[1]} but its camera is "
                            f"{v.width}x{v.height}")
        sizes.append(wh or (v.width, v.height))
    check_image_budget(sizes, downscale)

