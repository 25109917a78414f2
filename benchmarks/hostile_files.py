"""Writers of hostile files for the hostile-input table (benchmarks/hostile_inputs.py): crafted PNG/JPEG/BMP headers,
alpha channels, colour views, symbolic links, JSON that is not UTF-8 or nested 200,000 deep. Each writer takes the
tiny scene's folder (4 views ``view_0i.png``, 32x24, and ``transforms.json``) and changes it in place; some return
overrides that replace the default ``dataset.path``.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

__all__ = ["bmp_declaring", "colour_views", "grey_views", "jpeg_declaring", "json_edit", "json_text", "png_declaring",
           "rgba_views", "symlink_loop"]

W, H, N = 32, 24, 4  # the tiny scene of benchmarks/hostile_inputs.py


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_declaring(view: str, w: int, h: int, rows: int = 64):
    """A PNG whose header declares ``w x h`` grey pixels and whose data holds ``rows`` zero rows (a bomb)."""
    def write(root: Path) -> None:
        data = zlib.compress(b"\x00" * ((w + 1) * rows), 9)
        png = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
        (root / f"{view}.png").write_bytes(png + _chunk(b"IDAT", data) + _chunk(b"IEND", b""))
    return write


def jpeg_declaring(w: int, h: int):
    """``view_01`` as a JPEG whose start-of-frame declares ``w x h`` (the scan data stays 32x24)."""
    def write(root: Path) -> None:
        _, buf = cv2.imencode(".jpg", np.full((H, W), 128, np.uint8))
        data = bytearray(buf.tobytes())
        sof = data.index(b"\xff\xc0")
        data[sof + 5:sof + 9] = struct.pack(">HH", h, w)
        (root / "view_01.jpg").write_bytes(bytes(data))
        json_edit(lambda m: m["frames"][1].update(file_path="view_01.jpg"))(root)
    return write


def bmp_declaring(w: int, h: int):
    """``view_01`` as a BMP whose header declares ``w x h``."""
    def write(root: Path) -> None:
        _, buf = cv2.imencode(".bmp", np.full((H, W), 128, np.uint8))
        data = bytearray(buf.tobytes())
        data[18:26] = struct.pack("<ii", w, h)
        (root / "view_01.bmp").write_bytes(bytes(data))
        json_edit(lambda m: m["frames"][1].update(file_path="view_01.bmp"))(root)
    return write


def rgba_views(alpha: int, views=range(N), bits: int = 8, grey_alpha: bool = False):
    """``views`` as RGBA (or grey+alpha, written with PIL) PNGs whose alpha is ``alpha`` everywhere."""
    def write(root: Path) -> None:
        rng = np.random.default_rng(3)
        top = 255 if bits == 8 else 65535
        dtype = np.uint8 if bits == 8 else np.uint16
        for i in views:
            grey = rng.integers(0, top + 1, (H, W, 1)).astype(dtype)
            if grey_alpha:
                from PIL import Image

                la = np.concatenate([grey, np.full_like(grey, alpha)], -1).astype(np.uint8)
                Image.fromarray(la, "LA").save(root / f"view_{i:02d}.png")
                continue
            img = np.concatenate([grey, grey, grey, np.full_like(grey, alpha)], -1)
            cv2.imwrite(str(root / f"view_{i:02d}.png"), img)
    return write


def grey_views(ext: str, colour_file: bool = True):
    """Every view re-written as ``ext`` holding grey content, as a 3-channel (colour) file where ``colour_file``."""
    def write(root: Path) -> None:
        rng = np.random.default_rng(4)
        for i in range(N):
            g = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 0)
            img = cv2.merge([g, g, g]) if colour_file else g
            (root / f"view_{i:02d}.png").unlink()
            cv2.imwrite(str(root / f"view_{i:02d}{ext}"), img)
        json_edit(lambda m: [f.update(file_path=f["file_path"].replace(".png", ext)) for f in m["frames"]])(root)
    return write


def colour_views(ext: str = ".png", bits: int = 8):
    """Every view re-written as ``ext`` with colour content (channels far apart)."""
    def write(root: Path) -> None:
        rng = np.random.default_rng(5)
        top, dtype = (255, np.uint8) if bits == 8 else (65535, np.uint16)
        for i in range(N):
            img = rng.integers(0, top + 1, (H, W, 3)).astype(dtype)
            (root / f"view_{i:02d}.png").unlink()
            cv2.imwrite(str(root / f"view_{i:02d}{ext}"), img)
        json_edit(lambda m: [f.update(file_path=f["file_path"].replace(".png", ext)) for f in m["frames"]])(root)
    return write


def symlink_loop(target: str = "view_01.png"):
    """``target`` (relative to the scene) replaced by a symbolic link to itself."""
    def write(root: Path) -> None:
        (root / target).unlink(missing_ok=True)
        os.symlink(target, root / target)
    return write


def json_edit(edit):
    """``edit(meta)`` applied to the scene's transforms.json."""
    def write(root: Path) -> None:
        path = root / "transforms.json"
        meta = json.loads(path.read_text())
        edit(meta)
        path.write_text(json.dumps(meta))
    return write


def json_text(make):
    """transforms.json replaced by the bytes ``make(json text of the valid file)``."""
    def write(root: Path) -> None:
        path = root / "transforms.json"
        path.write_bytes(make(path.read_text()))
    return write
