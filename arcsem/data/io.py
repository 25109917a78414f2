"""File readers shared by the dataset readers: images, masks, arrays, PLY point clouds.

Every failure raises :class:`~arcsem.errors.DataError` naming the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError

__all__ = [
    "IMAGE_EXTS",
    "read_array",
    "read_image",
    "read_mask",
    "read_ply",
    "resize",
    "resolve_file",
    "write_ply",
]

IMAGE_EXTS = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".exr")


def resolve_file(base: Path, rel: str, what: str, exts: tuple[str, ...] = IMAGE_EXTS) -> Path:
    """``base / rel``; if it does not exist, try ``rel`` with each extension appended/replaced."""
    path = (base / rel).resolve()
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


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """8/16-bit or float PNG/TIFF/JPEG -> ``[H, W, 3]`` float32 in [0, 1] and alpha ``[H, W]`` or None.

    Grey images become three equal channels; colour images are returned as RGB.
    """
    cv2 = _cv2()
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataError(f"{path}: cannot read image (missing, corrupt or unsupported format)")
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    else:
        img = img.astype(np.float32)
        bad = ~np.isfinite(img)
        if bad.any():
            y, x = np.argwhere(bad)[0][:2]
            raise DataError(f"{path}: {int(bad.sum())} pixel value(s) are NaN or infinite (first at x={x}, y={y})")
        img = np.clip(img, 0.0, 1.0)
    if img.ndim == 2:
        img = img[..., None]
    alpha = None
    if img.shape[-1] in (2, 4):
        img, alpha = img[..., :-1], img[..., -1]
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, axis=-1)
    elif img.shape[-1] == 3:
        img = img[..., ::-1]  # BGR -> RGB
    else:
        raise DataError(f"{path}: unsupported channel count {img.shape[-1]}")
    return np.ascontiguousarray(img), alpha


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


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_header(f, path: Path) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    if f.readline().strip() != b"ply":
        raise DataError(f"{path}: not a PLY file")
    fmt, elements = None, []
    while True:
        line = f.readline()
        if not line:
            raise DataError(f"{path}: PLY header has no end_header")
        tok = line.decode("ascii", "replace").split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "end_header":
            return fmt, elements
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if tok[1] == "list":
                if elements[-1][0] == "vertex":
                    raise DataError(f"{path}: list properties in vertices are not supported")
                elements[-1][2].append((tok[-1], "list"))
            else:
                elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """PLY vertices -> points ``[P, 3]`` float32 and colours ``[P, 3]`` in [0, 1] (or None).

    Reads ``x, y, z`` and optional ``red, green, blue`` (uchar, or float in [0, 1]) of the ``vertex``
    element; ascii and binary little/big endian. The vertex element must come first.
    """
    with open(path, "rb") as f:
        fmt, elements = _ply_header(f, path)
        if not elements or elements[0][0] != "vertex":
            raise DataError(f"{path}: PLY has no leading 'vertex' element")
        _, count, props = elements[0]
        if fmt == "ascii":
            data = np.loadtxt(f, dtype=np.float64, max_rows=count, ndmin=2)
            cols = {name: data[:, i] for i, (name, _) in enumerate(props)}
            types = dict(props)
        else:
            endian = "<" if fmt == "binary_little_endian" else ">"
            dtype = np.dtype([(name, endian + t) for name, t in props])
            rec = np.frombuffer(f.read(dtype.itemsize * count), dtype=dtype, count=count)
            cols, types = {n: rec[n] for n in rec.dtype.names}, dict(props)
    if not all(k in cols for k in "xyz"):
        raise DataError(f"{path}: PLY vertices lack x, y, z")
    pts = np.stack([cols[k] for k in "xyz"], -1).astype(np.float32)
    colors = None
    if all(k in cols for k in ("red", "green", "blue")):
        colors = np.stack([cols[k] for k in ("red", "green", "blue")], -1).astype(np.float32)
        if types["red"] in ("u1", "i1") or colors.max() > 1.0:
            colors = colors / 255.0
    return pts, colors


def write_ply(path: Path, points: np.ndarray, colors: np.ndarray | None = None) -> None:
    """Binary little-endian PLY with ``x, y, z`` float and optional ``red, green, blue`` uchar."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.zeros(len(points), dtype=fields)
    for i, k in enumerate("xyz"):
        rec[k] = points[:, i]
    if colors is not None:
        c = np.clip(np.round(np.asarray(colors) * 255), 0, 255).astype(np.uint8)
        rec["red"], rec["green"], rec["blue"] = c[:, 0], c[:, 1], c[:, 2]
    names = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}"]
    header += [f"property {names[t]} {n}" for n, t in fields] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
