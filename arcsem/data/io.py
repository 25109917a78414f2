"""File readers shared by the dataset readers: images, masks, arrays (PLY point clouds: :mod:`.ply`).

Every failure raises :class:`~arcsem.errors.DataError` naming the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError
from ..ply import read_points, write_points
from ..sem.image import Levels, levels, orient, read_tiff, to_levels

__all__ = [
    "GREY_TOLERANCE",
    "IMAGE_EXTS",
    "LUMA",
    "dataset_root",
    "grey_if_equal_channels",
    "luminance",
    "read_array",
    "read_image",
    "read_image_levels",
    "read_mask",
    "read_ply",
    "resize",
    "resolve_file",
    "write_ply",
]

read_ply, write_ply = read_points, write_points  # the point-cloud names the readers use (arcsem.ply)

IMAGE_EXTS = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".webp", ".exr")

GREY_TOLERANCE = 4 / 255
"""An RGB image is grey content when its channels differ by more than this at no more than 0.1 % of its pixels
(a grey picture saved as colour PNG or JPEG: JPEG's colour conversion leaves differences of 1/255 or 2/255)."""


def dataset_root(path: str | Path) -> Path:
    """``dataset.path`` made absolute (symbolic links followed); DataError for a link that loops and for an image
    file (the reader wants the dataset's folder or its description file)."""
    try:
        root = Path(path).expanduser().resolve()
    except (RuntimeError, OSError) as exc:  # a symlink loop (RuntimeError before Python 3.13, OSError ELOOP after)
        raise DataError(f"dataset.path: {path} is a symbolic link that loops ({type(exc).__name__})") from None
    if root.is_file() and root.suffix.lower() in IMAGE_EXTS:
        raise DataError(f"dataset.path: {root} is an image file; give the dataset's folder (the one that holds "
                        "transforms.json or the COLMAP model)")
    return root


def resolve_file(base: Path, rel: str, what: str, exts: tuple[str, ...] = IMAGE_EXTS) -> Path:
    """``base / rel``; if it does not exist, try ``rel`` with each extension appended/replaced."""
    if "\x00" in rel:
        raise DataError(f"{what}: the file name {rel!r} holds a NUL character")
    try:
        path = (base / rel).resolve()
    except (RuntimeError, OSError) as exc:  # a symlink loop (RuntimeError before Python 3.13, OSError ELOOP after)
        raise DataError(f"{what}: {base / rel}: a symbolic link that loops ({type(exc).__name__}); "
                        "point it at a real file") from None
    if path.is_file():
        return path
    for ext in exts:
        for cand in (path.with_name(path.name + ext), path.with_suffix(ext)):
            if cand.is_file():
                return cand
    raise DataError(f"{what}: file not found: {path}")


def _cv2():
    import cv2

    return cv2


def _read_pixels(path: Path) -> tuple[np.ndarray, bool, Levels]:
    """The stored array of an image (uint8/uint16, or float within [0, 1]), whether its channels are BGR (OpenCV)
    rather than RGB (TIFF), and the intensity range of the file that was mapped to it
    (:func:`arcsem.sem.image.levels`: a float or 32-bit image of raw counts is not clipped to white)."""
    if Path(path).suffix.lower() in (".tif", ".tiff"):  # every compression, the Orientation tag applied
        tiff = read_tiff(Path(path), [])  # uint8/uint16 over the file's intensity range (its levels)
        return orient(tiff.pixels, tiff.orientation), False, tiff.levels
    from .headers import check_declared_size, image_header

    check_declared_size(Path(path), image_header(Path(path)))  # a decompression bomb is refused before decoding
    try:
        img = _cv2().imread(str(path), _cv2().IMREAD_UNCHANGED)
    except _cv2().error as exc:  # e.g. more pixels than CV_IO_MAX_IMAGE_PIXELS
        last = [ln.strip() for ln in str(exc).splitlines() if ln.strip()][-1]
        raise DataError(f"{path}: cannot decode the image (OpenCV: {last})") from None
    if img is None:
        raise DataError(f"{path}: cannot read image (missing, corrupt or unsupported format)")
    alpha = img.ndim == 3 and img.shape[-1] in (2, 4)
    if img.dtype.kind == "f":
        _finite(img, path)
    lv = levels(img[..., :-1] if alpha else img)
    if (lv.lo, lv.hi) != (0.0, 1.0) or img.dtype.kind != "f":  # floats within [0, 1] are kept as they are
        img = to_levels(img, lv, alpha)
    return img, True, lv


def _finite(img: np.ndarray, path: Path) -> None:
    bad = ~np.isfinite(img)
    if bad.any():
        y, x = np.argwhere(bad)[0][:2]
        raise DataError(f"{path}: {int(bad.sum())} pixel value(s) are NaN or infinite (first at x={x}, y={y})")


def read_image_levels(path: Path) -> tuple[np.ndarray, np.ndarray | None, Levels]:
    """:func:`read_image` and the intensity range of the file mapped to ``[0, 1]`` (``Levels``: black and white
    level, and where they came from: the file's tags, its sample type, or the data's own percentiles)."""
    img, bgr, lv = _read_pixels(path)
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    else:
        img = np.clip(img.astype(np.float32), 0.0, 1.0)
    if img.ndim == 2:
        img = img[..., None]
    alpha = None
    if img.shape[-1] in (2, 4):
        img, alpha = img[..., :-1], img[..., -1]
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, axis=-1)
    elif img.shape[-1] != 3:
        raise DataError(f"{path}: unsupported channel count {img.shape[-1]}")
    elif bgr:
        img = img[..., ::-1]  # BGR -> RGB
    return np.ascontiguousarray(img), alpha, lv


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """8/16/32-bit or float PNG/TIFF/JPEG/EXR -> ``[H, W, 3]`` float32 in [0, 1] and alpha ``[H, W]`` or None.

    Grey images become three equal channels; colour images are returned as RGB. TIFFs are read with tifffile
    (:func:`arcsem.sem.image.read_tiff`: any compression, first page), the rest with OpenCV. Samples are mapped
    from the file's intensity range (:func:`read_image_levels`), so raw detector counts are not clipped.
    """
    img, alpha, _ = read_image_levels(path)
    return img, alpha


LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
"""Rec. 709 luminance weights: a colour view's grey (``dataset.grey=true``, the public colour scenes)."""


def luminance(rgb: np.ndarray) -> np.ndarray:
    """``[..., 3]`` colour -> ``[..., 3]``: its Rec. 709 luminance in every channel (grey as the readers store it)."""
    lum = rgb[..., :3].astype(np.float32) @ LUMA
    return np.ascontiguousarray(np.repeat(lum[..., None], 3, axis=-1))


def channel_spread(img: np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` -> ``[H, W]``: max minus min of the three channels, as the largest of the three pairwise
    differences (16x faster than ``max(-1) - min(-1)``, a reduction over a 3-long axis: benchmarks/io_speed.py)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return np.maximum(np.maximum(np.abs(r - g), np.abs(g - b)), np.abs(r - b))


def grey_if_equal_channels(img: np.ndarray) -> tuple[np.ndarray, float]:
    """``[H, W, 3]`` -> itself, or its channel mean three times where it is grey content (:data:`GREY_TOLERANCE`);
    and the fraction of pixels whose channels differ by more than the tolerance (0: grey)."""
    spread = channel_spread(img)
    if not spread.any():
        return img, 0.0
    coloured = float(np.mean(spread > GREY_TOLERANCE))
    if coloured > 1e-3:
        return img, coloured
    mean = (img[..., 0] + img[..., 1] + img[..., 2]) / 3  # = img.mean(-1), 14x faster (a 3-long reduction)
    return np.repeat(mean[..., None], 3, axis=-1), 0.0


def read_mask(path: Path) -> np.ndarray:
    """Mask image -> ``[H, W]`` bool (a pixel is inside when its first channel / alpha > 0.5)."""
    img, alpha = read_image(path)
    return (alpha if alpha is not None and img.max() == 0 else img[..., 0]) > 0.5


def read_array(path: Path, shape_hw: tuple[int, int], channels: int | None, what: str) -> np.ndarray:
    """``.npy`` array ``[H, W]`` (channels None) or ``[H, W, channels]`` as float32, shape-checked."""
    try:
        arr = np.load(path).astype(np.float32)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read {what}: {exc}") from None
    want = shape_hw if channels is None else (*shape_hw, channels)
    if arr.shape != want:
        raise DataError(f"{path}: {what} has shape {arr.shape}, expected {want}")
    return arr


def resize(arr: np.ndarray, size_wh: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """Resize ``[H, W]`` or ``[H, W, C]`` to ``(w, h)``: INTER_AREA (images), INTER_NEAREST (depth)."""
    cv2 = _cv2()
    if (arr.shape[1], arr.shape[0]) == tuple(size_wh):
        return arr
    out = cv2.resize(arr, size_wh, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    return out.reshape(size_wh[1], size_wh[0], *arr.shape[2:])
