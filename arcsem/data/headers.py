"""Image sizes read from file headers (no pixel decoded) and the memory a dataset needs, checked before it is read.

A PNG that declares 40000x40000 pixels in a few MB of zeros (a decompression bomb), or three 12000x12000 views
on a machine with 4 GB, must end with one line naming the file and the figure, not with OpenCV's assertion or
the kernel's OOM killer. :func:`image_header` reads the width and height of PNG, JPEG and BMP files from
their first bytes and of TIFFs from their first page's tags; :func:`check_image_budget` refuses an image above
:data:`MAX_PIXELS` and a dataset whose reading would need more memory than this process may use, with the
``dataset.downscale`` that would fit.
"""
from __future__ import annotations

import math
import resource
import struct
from pathlib import Path

from ..errors import DataError

__all__ = ["MAX_PIXELS", "available_memory", "check_declared_size", "check_image_budget", "image_header", "load_bytes"]

MAX_PIXELS = 2**30
"""Largest image arcsem decodes: OpenCV's ``CV_IO_MAX_IMAGE_PIXELS`` (1073.7 megapixels)."""

_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}  # JPEG start-of-frame markers


def _png(head: bytes) -> tuple[int, int] | None:
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])
    return None


def _jpeg(path: Path) -> tuple[int, int] | None:
    """Width and height of the first start-of-frame segment (walks the marker segments; reads no scan data)."""
    with open(path, "rb") as f:
        if f.read(2) != b"\xff\xd8":
            return None
        while True:
            marker = f.read(2)
            if len(marker) < 2 or marker[0] != 0xFF:
                return None
            if marker[1] in (0xD8, 0x01) or 0xD0 <= marker[1] <= 0xD7:  # markers without a length
                continue
            length = f.read(2)
            if len(length) < 2:
                return None
            if marker[1] in _SOF:
                data = f.read(5)
                return (struct.unpack(">H", data[3:5])[0], struct.unpack(">H", data[1:3])[0]) if len(data) == 5 \
                    else None
            f.seek(struct.unpack(">H", length)[0] - 2, 1)


def _tiff(path: Path) -> tuple[int, int] | None:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            return int(page.imagewidth), int(page.imagelength)
    except Exception:  # noqa: BLE001 (not a readable TIFF: the decoder names the problem)
        return None


def image_header(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` declared by the header of a PNG, JPEG, BMP or TIFF file; None for other formats or
    a header that cannot be parsed (the decoder then reports the file)."""
    try:
        with open(path, "rb") as f:
            head = f.read(32)
        if head[:2] == b"\xff\xd8":
            return _jpeg(path)
        if head[:2] == b"BM" and len(head) >= 26:
            w, h = struct.unpack("<ii", head[18:26])
            return abs(w), abs(h)
        if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
            return _tiff(path)
        return _png(head)
    except (OSError, struct.error):
        return None


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_available() -> int | None:
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text())
    except (OSError, ValueError):
        return None


def _address_space_left() -> int | None:
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        used = int(Path("/proc/self/status").read_text().split("VmSize:")[1].split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        used = 0
    return soft - used


def available_memory() -> tuple[int, str] | None:
    """``(bytes, what limits it)``: the least of the free memory, the cgroup's limit and the address-space limit
    (``ulimit -v``) left to this process; None where none can be read."""
    found = [(v, what) for v, what in ((_meminfo_available(), "free memory"),
                                      (_cgroup_available(), "the container's memory limit"),
                                      (_address_space_left(), "the address-space limit, ulimit -v"))
             if v is not None]
    return min(found) if found else None


def load_bytes(sizes: list[tuple[int, int]], downscale: float) -> int:
    """Peak bytes of reading views of ``sizes`` ``[(w, h)]`` at ``1 / downscale``: every view kept as float32 RGB
    and stacked once (twice the kept images), or the kept images plus one full-size decode (its float copies)."""
    kept = sum(round(w / downscale) * round(h / downscale) * 12 for w, h in sizes)
    decode = max(w * h for w, h in sizes) * 40  # 16-bit samples, float32 RGB, its clipped and contiguous copies
    return max(2 * kept, kept + decode)


def _gb(n: float) -> str:
    return f"{n / 1e9:.1f} GB"


def check_declared_size(path: Path, wh: tuple[int, int] | None) -> None:
    """DataError when the header of ``path`` declares ``wh`` (width, height) above :data:`MAX_PIXELS`."""
    if wh is not None and wh[0] * wh[1] > MAX_PIXELS:
        raise DataError(f"{path}: the file declares {wh[0]}x{wh[1]} px ({wh[0] * wh[1] / 1e6:.0f} megapixels); "
                        f"arcsem decodes images of at most {MAX_PIXELS / 1e6:.0f} megapixels (a damaged or "
                        "crafted file?)")


def check_image_budget(sizes: list[tuple[int, int]], downscale: float) -> None:
    """DataError when views of ``sizes`` ``[(w, h)]`` need more memory to read at ``1 / downscale`` than
    :func:`available_memory` (90 % of it), with the ``dataset.downscale`` that would fit."""
    have = available_memory()
    need = load_bytes(sizes, downscale)
    if have is None or need <= 0.9 * have[0]:
        return
    fits = next((d for d in range(math.floor(downscale) + 1, 65) if load_bytes(sizes, d) <= 0.9 * have[0]), None)
    w, h = max(sizes, key=lambda s: s[0] * s[1])
    advice = (f"use dataset.downscale={fits} (about {_gb(load_bytes(sizes, fits))})" if fits
              else "one image alone does not fit; crop or shrink the images first")
    raise DataError(f"dataset: reading {len(sizes)} view(s) of up to {w}x{h} px at downscale {downscale:g} needs "
                    f"about {_gb(need)} of memory, more than the {_gb(have[0])} available ({have[1]}); {advice}")
