"""PLY vertex files through ``plyfile``: the one reader and writer of point clouds and Gaussian splat files.

:func:`read_vertices` returns a PLY's ``vertex`` element as named columns (ascii or binary, any endianness,
any scalar type); :func:`write_vertices` writes named columns as a binary little-endian PLY, atomically.
Point clouds (``x y z`` and optional ``red green blue``) and the 3DGS/2DGS layout
(:mod:`arcsem.backbones.gaussians.ply`) are built on these two.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import DataError
from .files import atomic_open

__all__ = ["read_points", "read_vertices", "write_points", "write_vertices"]


def read_vertices(path: str | Path) -> dict[str, np.ndarray]:
    """The ``vertex`` element of a PLY as ``{property: [P] array}`` (list properties are refused)."""
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such PLY file")
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"]
        data = vertex.data
    except KeyError:
        raise DataError(f"{path}: PLY has no 'vertex' element") from None
    except (PlyParseError, ValueError, EOFError, OSError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        what = "not a PLY file" if "expected 'ply'" in text else "truncated or corrupt PLY file"
        raise DataError(f"{path}: {what} ({text})") from None
    names = data.dtype.names or ()
    if any(data.dtype[n].shape or data.dtype[n] == object for n in names):
        raise DataError(f"{path}: list properties in vertices are not supported")
    return {n: np.asarray(data[n]) for n in names}


def write_vertices(path: str | Path, columns: dict[str, np.ndarray], comments: list[str] | None = None) -> None:
    """Write ``columns`` (``{property: [P] array}``, in order; dtypes kept) as a binary little-endian PLY."""
    from plyfile import PlyData, PlyElement

    n = len(next(iter(columns.values()))) if columns else 0
    rec = np.empty(n, dtype=[(k, np.asarray(v).dtype.newbyteorder("<")) for k, v in columns.items()])
    for k, v in columns.items():
        rec[k] = v
    ply = PlyData([PlyElement.describe(rec, "vertex")], text=False, byte_order="<", comments=comments or [])
    with atomic_open(path, "wb") as f:
        ply.write(f)


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """PLY vertices -> points ``[P, 3]`` float32 and colours ``[P, 3]`` in [0, 1] (or None): ``x, y, z`` and
    optional ``red, green, blue`` (integers 0..255, or floats in [0, 1])."""
    cols = read_vertices(path)
    if not all(k in cols for k in "xyz"):
        raise DataError(f"{path}: PLY vertices lack x, y, z")
    pts = np.stack([cols[k] for k in "xyz"], -1).astype(np.float32)
    colors = None
    if all(k in cols for k in ("red", "green", "blue")):
        rgb = np.stack([cols[k] for k in ("red", "green", "blue")], -1)
        colors = rgb.astype(np.float32)
        if np.issubdtype(rgb.dtype, np.integer) or colors.max() > 1.0:
            colors = colors / 255.0
    return pts, colors


def write_points(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None) -> None:
    """Points ``[P, 3]`` as float ``x, y, z`` and, with ``colors [P, 3]`` in [0, 1], uchar ``red, green, blue``."""
    points = np.asarray(points, dtype=np.float32)
    columns = {k: points[:, i] for i, k in enumerate("xyz")}
    if colors is not None:
        c = np.clip(np.round(np.asarray(colors) * 255), 0, 255).astype(np.uint8)
        columns.update(red=c[:, 0], green=c[:, 1], blue=c[:, 2])
    write_vertices(path, columns)
