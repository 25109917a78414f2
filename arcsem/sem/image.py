"""One SEM image from disk: grey pixels at their bit depth, upright, and its vendor metadata.

TIFF files are read with ``tifffile`` and ``imagecodecs`` (every compression: LZW, Deflate, PackBits, JPEG,
ZSTD, LZMA, JPEG 2000; first page; tiled or in strips; palette images through their colour map; the TIFF
``Orientation`` tag applied); PNG, JPEG and BMP with OpenCV (JPEG: EXIF orientation applied by OpenCV).
Metadata: TIFF tags 34118 (Zeiss), 34682 (FEI/Thermo Fisher), 50431 (TESCAN), else a sidecar next to
the image: ``<stem>.hdr`` (TESCAN), ``<stem>.txt`` (Hitachi ``[SemImageFile]`` or JEOL ``$CM_FORMAT``).
The raw tag bytes are parsed by :mod:`arcsem.sem.metadata` (tifffile's own decoders are not used).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from .metadata import SemMeta, parse_fei, parse_hitachi, parse_jeol, parse_tescan, parse_zeiss

__all__ = ["IMAGE_SUFFIXES", "SemImage", "orient", "read_sem_image", "read_tiff", "to_unit"]

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp")
_TAGS = {34118: parse_zeiss, 34682: parse_fei, 50431: parse_tescan}
# TIFF Orientation (1..8) -> operations on the stored array that make it upright
_ORIENT = {1: (), 2: ("fliplr",), 3: ("rot180",), 4: ("flipud",), 5: ("transpose",), 6: ("rot270",),
           7: ("transpose", "rot180"), 8: ("rot90",)}


@dataclass
class SemImage:
    """A grey SEM image ``pixels [H, W]`` (uint8 or uint16, upright) with its metadata.

    ``orientation``: the TIFF/EXIF orientation that was applied (1 = as stored); ``notes``: what else
    the reader did (page chosen, colour converted).
    """

    path: Path
    pixels: np.ndarray
    meta: SemMeta
    orientation: int = 1
    notes: list[str] = field(default_factory=list)

    @property
    def bits(self) -> int:
        return 16 if self.pixels.dtype == np.uint16 else 8

    @property
    def size(self) -> tuple[int, int]:
        """``(w, h)``."""
        return self.pixels.shape[1], self.pixels.shape[0]


def to_unit(pixels: np.ndarray) -> np.ndarray:
    """uint8/uint16 ``[H, W]`` -> float32 in ``[0, 1]``."""
    return pixels.astype(np.float32) / (65535.0 if pixels.dtype == np.uint16 else 255.0)


def _grey(arr: np.ndarray, path: Path, notes: list[str]) -> np.ndarray:
    """``[H, W]`` or ``[H, W, C]`` of any integer/float type -> uint8/uint16 ``[H, W]``."""
    if arr.ndim == 3:
        if arr.shape[-1] in (2, 4):
            arr = arr[..., :-1]
        if arr.shape[-1] == 3 and not (np.array_equal(arr[..., 0], arr[..., 1]) and np.array_equal(arr[..., 1], arr[..., 2])):
            notes.append("colour converted to grey")
            arr = (arr[..., 0] * 0.299 + arr[..., 1] * 0.587 + arr[..., 2] * 0.114).astype(arr.dtype)
        else:
            arr = arr[..., 0]
    if arr.ndim != 2:
        raise DataError(f"{path}: unsupported image shape {arr.shape} (expected a grey or RGB image)")
    if arr.dtype in (np.uint8, np.uint16):
        return arr
    if np.issubdtype(arr.dtype, np.floating):
        bad = ~np.isfinite(arr)
        if bad.any():
            raise DataError(f"{path}: {int(bad.sum())} pixel value(s) are NaN or infinite")
        lo, hi = float(arr.min()), float(arr.max())
        notes.append(f"float image rescaled from [{lo:.3g}, {hi:.3g}] to 16 bits")
        return np.round((arr - lo) / max(hi - lo, 1e-12) * 65535).astype(np.uint16)
    if np.issubdtype(arr.dtype, np.integer):
        notes.append(f"{arr.dtype} image clipped to 16 bits")
        return np.clip(arr, 0, 65535).astype(np.uint16)
    raise DataError(f"{path}: unsupported pixel type {arr.dtype}")


def orient(arr: np.ndarray, code: int) -> np.ndarray:
    """``arr [H, W, ...]`` as stored -> upright, by the TIFF/EXIF orientation ``code`` (1..8)."""
    for op in _ORIENT.get(code, ()):
        arr = {"fliplr": np.fliplr, "flipud": np.flipud, "transpose": np.transpose,
               "rot90": np.rot90, "rot180": lambda a: np.rot90(a, 2), "rot270": lambda a: np.rot90(a, 3)}[op](arr)
    return np.ascontiguousarray(arr)


def _tag_text(tif, tag) -> str:
    """The raw bytes of a TIFF tag as text (Latin-1; NUL bytes dropped)."""
    fh = tif.filehandle
    fh.seek(tag.valueoffset)
    raw = fh.read(tag.valuebytecount)
    return raw.replace(b"\x00", b"").decode("latin-1")


def read_tiff(path: Path, notes: list[str]) -> tuple[np.ndarray, int, SemMeta | None]:
    """The first page of a TIFF as stored (any compression: tifffile with imagecodecs), its Orientation tag and its
    vendor metadata. The one TIFF reader of arcsem (datasets too: :func:`arcsem.data.io.read_image`)."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            if len(tif.pages) > 1:
                notes.append(f"{len(tif.pages)} pages: the first is used")
            arr = page.asarray()
            if page.photometric == tifffile.PHOTOMETRIC.PALETTE and page.colormap is not None:
                cmap = np.asarray(page.colormap, dtype=np.float64)  # [3, 2^bits] 16-bit RGB
                lum = (cmap[0] * 0.299 + cmap[1] * 0.587 + cmap[2] * 0.114) / 65535.0
                arr = np.round(lum[arr] * 255).astype(np.uint8)
                notes.append("palette image: colour map applied")
            orientation = int(page.tags[274].value) if 274 in page.tags else 1
            meta = None
            for code, parse in _TAGS.items():
                if code in page.tags:
                    meta = parse(_tag_text(tif, page.tags[code]))
                    break
    except (tifffile.TiffFileError, ValueError, OSError, IndexError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "imagecodecs" in why:  # a codec this installation lacks: say what to install
            why += "; install it with pip install imagecodecs (a dependency of arcsem: reinstall with make setup)"
        raise DataError(f"{path}: cannot read TIFF ({why})") from None
    return arr, orientation, meta


def _read_other(path: Path) -> np.ndarray:
    import cv2

    flag = cv2.IMREAD_UNCHANGED if path.suffix.lower() != ".jpg" and path.suffix.lower() != ".jpeg" else cv2.IMREAD_GRAYSCALE
    arr = cv2.imread(str(path), flag)
    if arr is None:
        raise DataError(f"{path}: cannot read image (corrupt or unsupported format)")
    if arr.ndim == 3 and arr.shape[-1] >= 3:
        arr = np.concatenate([arr[..., 2::-1], arr[..., 3:]], axis=-1)  # BGR(A) -> RGB(A)
    return arr


def _sidecar(path: Path) -> SemMeta | None:
    """Metadata from ``<stem>.hdr`` (TESCAN) or ``<stem>.txt`` (Hitachi, JEOL), or None."""
    hdr = path.with_suffix(".hdr")
    if hdr.is_file():
        return parse_tescan(_text(hdr), f"sidecar {hdr.name}")
    txt = path.with_suffix(".txt")
    if txt.is_file():
        text = _text(txt)
        if "[SemImageFile]" in text:
            return parse_hitachi(text, f"sidecar {txt.name}")
        if "$CM_" in text or "$$SM_" in text:
            return parse_jeol(text, f"sidecar {txt.name}")
    return None


def _text(path: Path) -> str:
    """A sidecar's text: UTF-16 when it has a BOM or NUL bytes (Hitachi), else UTF-8 or Latin-1."""
    raw = path.read_bytes()
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff") or (raw and raw.count(b"\x00") > len(raw) // 4):
        return raw.decode("utf-16", errors="replace")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_sem_image(path: str | Path) -> SemImage:
    """Read ``path`` (see the module docstring); DataError naming the file when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such image file")
    notes: list[str] = []
    meta, orientation = None, 1
    if path.suffix.lower() in (".tif", ".tiff"):
        arr, orientation, meta = read_tiff(path, notes)
        arr = orient(arr, orientation)
    else:
        arr = _read_other(path)
    pixels = _grey(arr, path, notes)
    if meta is None:
        meta = _sidecar(path) or SemMeta(source="no vendor metadata found")
    return SemImage(path=path, pixels=pixels, meta=meta, orientation=orientation, notes=notes)
