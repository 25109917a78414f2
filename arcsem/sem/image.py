"""One SEM image from disk: grey pixels at their bit depth, upright, and its vendor metadata.

TIFF files are read with ``tifffile`` and ``imagecodecs`` (every compression: LZW, Deflate, PackBits, JPEG,
ZSTD, LZMA, JPEG 2000; first page; tiled or in strips; palette images through their colour map; the TIFF
``Orientation`` tag applied); PNG, JPEG and BMP with OpenCV (JPEG: EXIF orientation applied by OpenCV).
Metadata: TIFF tags 34118 (Zeiss), 34682 (FEI/Thermo Fisher), 50431 (TESCAN), else a sidecar next to
the image: ``<stem>.hdr`` (TESCAN), ``<stem>.txt`` (Hitachi ``[SemImageFile]`` or JEOL ``$CM_FORMAT``).
The raw tag bytes are parsed by :mod:`arcsem.sem.metadata` (tifffile's own decoders are not used).

Intensity range (:func:`levels`): the black and white levels of the stored samples, from the file where it says
(TIFF ``SMinSampleValue``/``SMaxSampleValue``, ``MinSampleValue``/``MaxSampleValue``, else ``BitsPerSample``
for 8- to 16-bit unsigned integers: 12-bit data is 0..4095), floats within [0, 1] as they are, and otherwise
(32-bit integers, signed integers, floats of raw detector counts) the data's own 0.1 and 99.9 percentiles, per
file. Samples outside 8 or 16 bits unsigned are mapped to 16 bits over that range (clipped beyond it); the
range and where it came from are kept (:attr:`SemImage.levels`) for the inspection table and the dataset.
Colour images whose channels agree (within 1 % of the range) are grey; others are read as their luminance
with a warning naming the file (an SEM series is grey).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from .metadata import SemMeta, parse_fei, parse_hitachi, parse_jeol, parse_tescan, parse_zeiss

__all__ = ["IMAGE_SUFFIXES", "Levels", "SemImage", "Tiff", "levels", "orient", "read_sem_image", "read_tiff",
           "to_levels", "to_unit"]

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp")
_TAGS = {34118: parse_zeiss, 34682: parse_fei, 50431: parse_tescan}
# TIFF Orientation (1..8) -> operations on the stored array that make it upright
_ORIENT = {1: (), 2: ("fliplr",), 3: ("rot180",), 4: ("flipud",), 5: ("transpose",), 6: ("rot270",),
           7: ("transpose", "rot180"), 8: ("rot90",)}


@dataclass(frozen=True)
class Levels:
    """The black (``lo``) and white (``hi``) level of a file's samples and where they came from (``source``)."""

    lo: float
    hi: float
    source: str

    def describe(self) -> str:
        return f"{self.lo:.6g}..{self.hi:.6g} ({self.source})"


@dataclass
class SemImage:
    """A grey SEM image ``pixels [H, W]`` (uint8 or uint16, upright) with its metadata.

    ``orientation``: the TIFF/EXIF orientation that was applied (1 = as stored); ``levels``: the intensity
    range of the file mapped to the pixels' full range; ``notes``: what else the reader did (page chosen,
    colour converted).
    """

    path: Path
    pixels: np.ndarray
    meta: SemMeta
    orientation: int = 1
    levels: Levels | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def bits(self) -> int:
        return 16 if self.pixels.dtype == np.uint16 else 8

    @property
    def size(self) -> tuple[int, int]:
        """``(w, h)``."""
        return self.pixels.shape[1], self.pixels.shape[0]


@dataclass
class Tiff:
    """What :func:`read_tiff` read: ``pixels [H, W]`` or ``[H, W, C]`` uint8/uint16 as stored (not yet upright),
    the TIFF ``orientation`` (1..8), the vendor ``meta`` (None without a known tag) and the ``levels`` mapped."""

    pixels: np.ndarray
    orientation: int
    meta: SemMeta | None
    levels: Levels


def to_unit(pixels: np.ndarray) -> np.ndarray:
    """uint8/uint16 ``[H, W]`` -> float32 in ``[0, 1]``."""
    return pixels.astype(np.float32) / (65535.0 if pixels.dtype == np.uint16 else 255.0)


def _finite_check(arr: np.ndarray, path: Path) -> None:
    """DataError naming ``path`` when float samples ``arr`` hold NaN or infinity."""
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            y, x = np.argwhere(bad)[0][:2]
            raise DataError(f"{path}: {int(bad.sum())} pixel value(s) are NaN or infinite (first at x={x}, y={y})")


def _tag_range(tags: dict[int, object], lo_code: int, hi_code: int) -> tuple[float, float] | None:
    """``(min, max)`` of two range tags (per-sample tuples: their extremes), or None when absent or empty."""
    if hi_code not in tags:
        return None
    lo = float(np.min(np.asarray(tags.get(lo_code, 0), dtype=np.float64)))
    hi = float(np.max(np.asarray(tags[hi_code], dtype=np.float64)))
    return (lo, hi) if np.isfinite(lo) and np.isfinite(hi) and hi > lo else None


def levels(arr: np.ndarray, tags: dict[int, object] | None = None) -> Levels:
    """The intensity range of samples ``arr [H, W(, C)]`` (no alpha channel) given the file's TIFF ``tags``
    ``{code: value}`` (None for other files); see the module docstring for the order of the rules."""
    tags = tags or {}
    found = _tag_range(tags, 340, 341)
    if found:
        return Levels(*found, "SMinSampleValue/SMaxSampleValue tags")
    kind, bits = arr.dtype.kind, int(tags.get(258, 8 * arr.dtype.itemsize))
    if kind in "ui" and (found := _tag_range(tags, 280, 281)):
        return Levels(*found, "MinSampleValue/MaxSampleValue tags")
    if kind == "u" and arr.dtype.itemsize <= 2:
        return Levels(0.0, float(2 ** bits - 1), f"BitsPerSample {bits}" if 258 in tags else f"{bits}-bit samples")
    if kind == "f" and arr.size and arr.min() >= 0 and arr.max() <= 1:
        return Levels(0.0, 1.0, "float samples within [0, 1]")
    lo, hi = (float(v) for v in np.percentile(arr, (0.1, 99.9))) if arr.size else (0.0, 1.0)
    if hi <= lo:
        lo, hi = float(arr.min()), max(float(arr.max()), float(arr.min()) + 1.0)
    return Levels(lo, hi, "the data's 0.1/99.9 percentiles")


def to_levels(arr: np.ndarray, lv: Levels, alpha: bool = False) -> np.ndarray:
    """Samples ``arr [H, W(, C)]`` -> uint8/uint16: as they are when ``lv`` is their type's full range, else mapped
    from ``lv.lo..lv.hi`` to 0..65535 (clipped). ``alpha``: the last channel is opacity (float in [0, 1] or its
    integer type's range), mapped on its own."""
    full = {np.dtype(np.uint8): (0.0, 255.0), np.dtype(np.uint16): (0.0, 65535.0)}.get(arr.dtype)
    if full == (lv.lo, lv.hi):
        return arr
    colour = arr[..., :-1] if alpha else arr
    out = np.clip((colour.astype(np.float32) - np.float32(lv.lo)) / np.float32(lv.hi - lv.lo), 0.0, 1.0)
    if alpha:
        a = arr[..., -1:].astype(np.float32)
        a = np.clip(a, 0, 1) if arr.dtype.kind == "f" else a / float(np.iinfo(arr.dtype).max)
        out = np.concatenate([out, a], axis=-1)
    return np.round(out * 65535.0).astype(np.uint16)


def _grey(arr: np.ndarray, path: Path, notes: list[str]) -> np.ndarray:
    """uint8/uint16 ``[H, W]`` or ``[H, W, C]`` -> ``[H, W]``: alpha dropped, equal channels (within 1 % of the
    range at 99.9 % of the pixels) averaged, colour read as its luminance with a warning naming the file."""
    if arr.ndim == 3:
        if arr.shape[-1] in (2, 4):
            arr = arr[..., :-1]
        if arr.shape[-1] == 3:
            spread = arr.max(-1).astype(np.int64) - arr.min(-1)
            if np.percentile(spread, 99.9) <= 0.01 * np.iinfo(arr.dtype).max:
                arr = np.round(arr.mean(-1)).astype(arr.dtype)
            else:
                notes.append("colour image read as its luminance")
                warnings.warn(f"{path}: a colour image (its channels differ) in a grey SEM series: read as its "
                              "luminance", stacklevel=3)
                arr = np.round(arr @ np.array([0.299, 0.587, 0.114])).astype(arr.dtype)
        elif arr.shape[-1] == 1:
            arr = arr[..., 0]
    if arr.ndim != 2:
        raise DataError(f"{path}: unsupported image shape {arr.shape} (expected a grey or RGB image)")
    return arr


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


def read_tiff(path: Path, notes: list[str]) -> Tiff:
    """The first page of a TIFF (any compression: tifffile with imagecodecs) as uint8/uint16 over its intensity
    range (:func:`levels`), its Orientation tag and vendor metadata (:class:`Tiff`). The one TIFF reader of
    arcsem (datasets too: :func:`arcsem.data.io.read_image`)."""
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
            tags = {c: page.tags[c].value for c in (258, 280, 281, 340, 341) if c in page.tags}
            tags[258] = int(np.max(tags.get(258, 8 * arr.dtype.itemsize)))
            if "palette image: colour map applied" in notes:  # 8-bit luminance now, whatever the index depth
                tags = {258: 8}
            alpha = arr.ndim == 3 and arr.shape[-1] in (2, 4) and bool(page.extrasamples)
            white0 = page.photometric == tifffile.PHOTOMETRIC.MINISWHITE
            samples = int(page.samplesperpixel)
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
    if arr.ndim > 3 or (arr.ndim == 3 and arr.shape[-1] > 4):
        raise DataError(f"{path}: an image of {samples} samples per pixel (stored shape {arr.shape}); arcsem reads "
                        "grey, grey+alpha, RGB and RGBA images")
    _finite_check(arr, path)
    if arr.dtype.kind == "b":  # bilevel
        tags[258], arr = 8, arr.astype(np.uint8) * np.uint8(255)
    lv = levels(arr[..., :-1] if alpha else arr, tags)
    pixels = to_levels(arr, lv, alpha)
    if white0:  # PhotometricInterpretation 0: the smallest sample is white
        colour = pixels[..., :-1] if alpha else pixels
        colour[...] = np.iinfo(pixels.dtype).max - colour
        lv = Levels(lv.lo, lv.hi, f"{lv.source}; min-is-white, inverted")
    return Tiff(pixels, orientation, meta, lv)


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
        tiff = read_tiff(path, notes)
        arr, orientation, meta, lv = orient(tiff.pixels, tiff.orientation), tiff.orientation, tiff.meta, tiff.levels
    else:
        arr = _read_other(path)
        alpha = arr.ndim == 3 and arr.shape[-1] in (2, 4)
        lv = levels(arr[..., :-1] if alpha else arr)
        arr = to_levels(arr, lv, alpha)
    pixels = _grey(arr, path, notes)
    if meta is None:
        meta = _sidecar(path) or SemMeta(source="no vendor metadata found")
    return SemImage(path=path, pixels=pixels, meta=meta, orientation=orientation, levels=lv, notes=notes)
