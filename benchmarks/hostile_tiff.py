"""The hostile-input table's TIFF rows (benchmarks/hostile_inputs.py): SEM files as microscopes and image tools write
them, read two ways.

- As a dataset's views (``arcsem stage=check`` on the tiny transforms scene, its four 32x24 views re-written as
  TIFF): every compression tifffile and imagecodecs write, tiled, multi-page, BigTIFF, big-endian, planar, every
  sample format (8/16/32-bit integers, signed, 16/32/64-bit floats of raw counts or within [0, 1]), photometric
  variants (palette, bilevel, min-is-white, RGB of grey content, colour, alpha), the Orientation tag, and broken
  or crafted files (NaN samples, zero bytes, truncated strips, a header declaring 40000x40000 px, an unknown
  compression code). Each valid file must be read over its real intensity range, which ``stage=check`` prints.
- As a raw series for ``arcsem-calibrate`` (``--inspect``, which reads every file and its vendor tag and prints
  where each number came from, or the calibration's own early checks): Zeiss tag 34118 and FEI tag 34682 variants,
  compressions, a series stored turned by 90 degrees, and bad metadata and files.
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

__all__ = ["raw_series", "tiff_cases", "tiff_views"]

N = 4  # views of the tiny scene (benchmarks/hostile_files.py)


def _grey(root: Path, i: int):
    import cv2

    return cv2.imread(str(root / f"view_{i:02d}.png"), cv2.IMREAD_GRAYSCALE)


def _retarget(root: Path, ext: str) -> None:
    path = root / "transforms.json"
    meta = json.loads(path.read_text())
    for f in meta["frames"]:
        f["file_path"] = f["file_path"].replace(".png", ext)
    path.write_text(json.dumps(meta))


def tiff_views(make=lambda g, i: g, views=range(N), **kw):
    """Every view re-written as ``view_0i.tif`` holding ``make(grey uint8 [H, W], i)``, with tifffile's ``kw``
    (compression, tile, photometric, ...); views outside ``views`` are written as plain TIFFs."""
    def write(root: Path) -> None:
        import tifffile

        for i in range(N):
            arr = make(_grey(root, i), i) if i in views else _grey(root, i)
            (root / f"view_{i:02d}.png").unlink()
            tifffile.imwrite(root / f"view_{i:02d}.tif", arr, metadata=None, **(kw if i in views else {}))
        _retarget(root, ".tif")
    return write


def _patch_tag(path: Path, code: int, value: int) -> None:
    """Overwrite the (inline, integer) value of tag ``code`` of the first page of TIFF ``path``."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        tag = tif.pages.first.tags[code]
        fmt = {3: "H", 4: "I", 16: "Q"}[int(tag.dtype)]
        offset, order = tag.valueoffset, tif.byteorder
    data = bytearray(path.read_bytes())
    data[offset:offset + struct.calcsize(fmt)] = struct.pack(order + fmt, value)
    path.write_bytes(bytes(data))


def patched(code: int, value: int, view: int = 1):
    """The TIFF views with tag ``code`` of ``view_0<view>.tif`` set to ``value`` (a crafted header)."""
    def write(root: Path) -> None:
        tiff_views()(root)
        _patch_tag(root / f"view_{view:02d}.tif", code, value)
    return write


def _truncated(root: Path) -> None:
    tiff_views(compression="lzw")(root)
    path = root / "view_01.tif"
    path.write_bytes(path.read_bytes()[:120])


def _counts(scale: float, dtype, offset: float = 0.0):
    return lambda g, i: (g.astype(np.float64) * scale + offset).astype(dtype)


def _rgb(colour: bool):
    def make(g, i):
        rgb = np.stack([g, g, g], -1)
        if colour:
            rgb[..., 0] = 255 - g
        return rgb
    return make


def _rgba(alpha: int):
    return lambda g, i: np.stack([g, g, g, np.full_like(g, alpha)], -1)


def _nan(g, i):
    out = g.astype(np.float32)
    out[3, 5] = np.nan
    return out


def _views() -> list:
    from hostile_cases import Case  # a function-level import: hostile_cases imports this module

    ok = ("check: OK",)
    lv8, lv16 = "intensity  0..255 (BitsPerSample 8)", "intensity  0..65535 (BitsPerSample 16)"
    pct = "(the data's 0.1/99.9 percentiles)"
    compressions = [("none", None), ("LZW", "lzw"), ("Deflate", "adobe_deflate"), ("PackBits", "packbits"),
                    ("JPEG", "jpeg"), ("ZSTD", "zstd"), ("LZMA", "lzma"), ("JPEG 2000", "jpeg2000"),
                    ("WebP (lossless)", "webp")]
    cases = []
    for name, comp in compressions:
        kw = {"compression": comp} if comp else {}
        if comp == "webp":
            kw["compressionargs"] = {"lossless": True}
        make = _rgb(False) if name.startswith("WebP") else (lambda g, i: g)  # WebP holds RGB only
        cases.append(Case(f"TIFF views, {name} compression", "ok", (*ok, "intensity  0..255"), tiff_views(make, **kw),
                          absent=("colour content",)))
    cases += [
        Case("TIFF views, LZW with horizontal predictor, 16-bit", "ok", (*ok, lv16),
             tiff_views(_counts(257, np.uint16), compression="lzw", predictor=True)),
        Case("TIFF views, Deflate with float predictor, float32 counts", "ok", (*ok, pct),
             tiff_views(_counts(200.0, np.float32), compression="adobe_deflate", predictor=True)),
        Case("TIFF views, tiled 16x16", "ok", (*ok, lv8), tiff_views(tile=(16, 16), compression="lzw")),
        Case("TIFF views, one row per strip", "ok", (*ok, lv8), tiff_views(rowsperstrip=1)),
        Case("TIFF views, two pages each", "ok", (*ok, lv8), tiff_views(lambda g, i: np.stack([g, 255 - g]))),
        Case("TIFF views, BigTIFF", "ok", (*ok, lv8), tiff_views(bigtiff=True)),
        Case("TIFF views, big-endian 16-bit", "ok", (*ok, lv16), tiff_views(_counts(257, np.uint16), byteorder=">")),
        Case("TIFF views, RGB planar (separate planes) of grey content", "ok", ok,
             tiff_views(_rgb(False), planarconfig="separate", photometric="rgb"), absent=("colour content",)),
        Case("TIFF views, RGB of grey content", "ok", ok, tiff_views(_rgb(False), photometric="rgb"),
             absent=("colour content",)),
        Case("TIFF views, RGB colour content", "warning", ("view_00.tif and 3 more", "colour content"),
             tiff_views(_rgb(True), photometric="rgb")),
        Case("TIFF views, RGBA with alpha 0 everywhere", "warning", ("view_00.tif and 3 more", "alpha"),
             tiff_views(_rgba(0), photometric="rgb", extrasamples=["unassalpha"])),
        Case("TIFF views, uint16 holding 12-bit data", "ok", (*ok, lv16), tiff_views(_counts(16, np.uint16))),
        Case("TIFF views, uint32 detector counts", "ok", (*ok, pct), tiff_views(_counts(1000, np.uint32))),
        Case("TIFF views, int32 counts", "ok", (*ok, pct), tiff_views(_counts(1000, np.int32, -50000))),
        Case("TIFF views, int16 with negative values", "ok", (*ok, pct), tiff_views(_counts(100, np.int16, -12000))),
        Case("TIFF views, int8", "ok", (*ok, pct), tiff_views(_counts(0.5, np.int8, -64))),
        Case("TIFF views, float16 within [0, 1]", "ok", (*ok, "float samples within [0, 1]"),
             tiff_views(_counts(1 / 255, np.float16))),
        Case("TIFF views, float32 within [0, 1]", "ok", (*ok, "float samples within [0, 1]"),
             tiff_views(_counts(1 / 255, np.float32))),
        Case("TIFF views, float32 raw counts 0..65535", "ok", (*ok, pct), tiff_views(_counts(257.0, np.float32))),
        Case("TIFF views, float64 negative counts", "ok", (*ok, pct), tiff_views(_counts(3.0, np.float64, -900))),
        Case("TIFF views, float32 constant image", "ok", ok, tiff_views(lambda g, i: np.full(g.shape, 7.5, np.float32))),
        Case("TIFF views, SMin/SMaxSampleValue tags", "ok", (*ok, "SMinSampleValue/SMaxSampleValue tags"),
             tiff_views(_counts(100.0, np.float32), extratags=[(340, 12, 1, -10.0, False), (341, 12, 1, 3e4, False)])),
        Case("TIFF views, palette with a grey colour map", "ok", ok,
             tiff_views(photometric="palette", colormap=np.tile(np.arange(256, dtype=np.uint16) * 257, (3, 1)))),
        Case("TIFF views, bilevel (1 bit)", "ok", (*ok, "intensity  0..255"), tiff_views(lambda g, i: g > 128)),
        Case("TIFF views, min-is-white", "ok", (*ok, "min-is-white"), tiff_views(photometric="miniswhite")),
        Case("TIFF views, stored turned with Orientation 6", "ok", ok,
             tiff_views(lambda g, i: np.ascontiguousarray(np.rot90(g)), extratags=[(274, 3, 1, 6, False)])),
        Case("TIFF view turned by 90 degrees without an Orientation tag", "error", ("view_01", "is 24x32",
                                                                                    "camera is 32x24"),
             tiff_views(lambda g, i: np.ascontiguousarray(np.rot90(g)), views=[1])),
        Case("TIFF views with a Zeiss tag", "ok", ok, tiff_views(compression="lzw", extratags=[
            (34118, 2, 0, b"AP_STAGE_AT_T\r\nStage at T = 3.0\r\n", True)])),
        Case("TIFF view with NaN samples", "error", ("view_01.tif", "NaN or infinite", "x=5, y=3"),
             tiff_views(_nan, views=[1])),
        Case("TIFF view with infinite samples", "error", ("view_02.tif", "NaN or infinite"),
             tiff_views(lambda g, i: np.where(g > 100, np.inf, g).astype(np.float32), views=[2])),
        Case("zero-byte TIFF", "error", ("view_01.tif", "cannot read"),
             lambda r: (tiff_views()(r), (r / "view_01.tif").write_bytes(b""))),
        Case("text file named .tif", "error", ("view_01.tif", "cannot read"),
             lambda r: (tiff_views()(r), (r / "view_01.tif").write_text("II*\x00 not really a TIFF"))),
        Case("TIFF with its strips cut off", "error", ("view_01.tif",), _truncated),
        Case("TIFF declaring 40000x40000 px", "error", ("view_01.tif", "declares 40000x40000 px"),
             lambda r: (patched(256, 40000)(r), _patch_tag(r / "view_01.tif", 257, 40000))),
        Case("TIFF with an unknown compression code", "error", ("view_01.tif", "cannot read TIFF"),
             patched(259, 60000)),
        Case("TIFF with 16 channels", "error", ("view_01.tif", "16 samples per pixel"),
             tiff_views(lambda g, i: np.repeat(g[None], 16, 0), views=[1], planarconfig="separate",
                        photometric="minisblack")),
    ]
    return cases


# --- raw series for arcsem-calibrate -----------------------------------------------------------------------------

W, H = 200, 140  # the raw series' scans (the real tag layouts of tests/test_sem_raw_series.py)


def _pixel_nm() -> float:
    from test_sem_raw_series import TRUE_UM

    return TRUE_UM * 1e3


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(120, 40, (h, w)), (0, 0), 1.5) + rng.normal(0, 8, (h, w))
    return np.clip(img, 0, 255).astype(np.uint8)


def raw_series(vendor: str = "zeiss", n: int = 3, compression=None, turned: bool = False, tilts=(-3.0, 0.0, 3.0),
               edit=lambda text, i: text, make=lambda img, i: img, degrees: bool = False):
    """A folder ``raw`` of ``n`` 200x140 TIFF scans (``img_<i>.tif``) with a Zeiss or FEI tag in its real layout
    (``vendor``; ``"none"``: no tag; FEI tilts in radians, or ``degrees``), the tilts ``tilts``; ``turned``: stored
    rotated by 90 degrees relative to the scan (the metadata's width and height); ``edit(text, i)`` changes a
    tag's text, ``make(img, i)`` the stored array."""
    def write(root: Path) -> None:
        import tifffile
        from test_sem_raw_series import fei, zeiss

        folder = root / "raw"
        folder.mkdir()
        for i in range(n):
            tilt = tilts[i % len(tilts)]
            code, text = (34118, zeiss(tilt, (W, H))) if vendor == "zeiss" else (34682, fei(tilt, degrees))
            img = make(_texture(H, W, i), i)
            if turned:
                img = np.ascontiguousarray(np.rot90(img))
            tags = [] if vendor == "none" else [(code, 2, 0, edit(text, i).encode("latin-1"), True)]
            tifffile.imwrite(folder / f"img_{i + 1}.tif", img, compression=compression, metadata=None, extratags=tags)
    return write


def _series() -> list:
    from hostile_cases import Case  # a function-level import: hostile_cases imports this module

    def calib(name, expect, needles, write, *args, absent=()):
        return Case(name, expect, needles, write, overrides=list(args), tool="calibrate", absent=absent)

    px = f"pixel size: {_pixel_nm():.2f} nm"
    ins = "--inspect"
    cases = [calib(f"raw series: {c} with a Zeiss tag", "ok", (px,), raw_series(compression=k), ins)
             for c, k in (("LZW", "lzw"), ("Deflate", "adobe_deflate"), ("PackBits", "packbits"), ("JPEG", "jpeg"),
                          ("ZSTD", "zstd"), ("uncompressed", None))]
    cases += [
        calib("raw series: FEI tag, tilts in radians", "ok", (px, "tilt: TIFF tag 34682"),
              raw_series("fei", compression="lzw"), ins),
        calib("raw series: FEI tag, tilts in degrees", "ok", (px, "degrees"),
              raw_series("fei", compression="lzw", degrees=True, tilts=(-9.0, 0.0, 9.0)), ins),
        calib("raw series: LZW Zeiss stored turned by 90 degrees", "ok", (px,), raw_series(compression="lzw",
                                                                                          turned=True), ins,
              absent=("resized after acquisition",)),
        calib("raw series: FEI stored turned by 90 degrees", "ok", (px,), raw_series("fei", turned=True), ins,
              absent=("resized after acquisition",)),
        calib("raw series: 16-bit Zeiss", "ok", (px, "levels: 0..65535"),
              raw_series(make=lambda img, i: img.astype(np.uint16) * 257), ins),
        calib("raw series: float32 counts", "ok", ("the data's 0.1/99.9 percentiles",),
              raw_series(make=lambda img, i: img.astype(np.float32) * 97.0), ins),
        calib("raw series: mixed compressions", "ok", (px,),
              lambda r: (raw_series(compression="lzw")(r), _recompress(r / "raw" / "img_2.tif", "jpeg")), ins),
        calib("raw series: RGB of grey content", "ok", (px,), raw_series(make=lambda img, i: np.stack([img] * 3, -1)),
              ins, absent=("colour image",)),
        calib("raw series: one colour image", "warning", ("img_2.tif", "colour image"),
              raw_series(make=lambda img, i: np.stack([img, 255 - img, img], -1) if i == 1 else img), ins),
        calib("raw series: Zeiss tilts x100", "error", ("img_1.tif", "Stage at T = -300.0", "give --tilts"),
              raw_series(tilts=(-300.0, 0.0, 300.0))),
        calib("raw series: negative Zeiss pixel size", "error", ("img_1.tif", "'Image Pixel Size = -"),
              raw_series(edit=lambda t, i: t.replace("Image Pixel Size = ", "Image Pixel Size = -"))),
        calib("raw series: Zeiss tag with no tilt", "error", ("img_1.tif", "no stage tilt", "--tilts"),
              raw_series(edit=lambda t, i: t.replace("Stage at T", "Stage at X"))),
        calib("raw series: FEI tag cut short", "error", ("img_1.tif", "no stage tilt"),
              raw_series("fei", edit=lambda t, i: t[:40])),
        calib("raw series: no tags, tilts given", "ok", ("tilt: --tilts",), raw_series("none"), ins,
              "--tilts=-3,0,3"),
        calib("raw series: no tags, --tilts -3,0,3 as two words", "ok", ("tilt: --tilts",), raw_series("none"), ins,
              "--tilts", "-3,0,3"),
        calib("raw series: --tilts count wrong", "error", ("--tilts has 2 value(s)", "3 images"), raw_series("none"),
              "--tilts=-3,0"),
        calib("raw series: --pixel-size nan", "error", ("--pixel-size nan",), raw_series(), "--pixel-size", "nan"),
        calib("raw series: a zero-byte TIFF", "error", ("img_2.tif", "cannot read"),
              lambda r: (raw_series()(r), (r / "raw" / "img_2.tif").write_bytes(b"")), ins),
        calib("raw series: NaN samples", "error", ("img_3.tif", "NaN or infinite"),
              raw_series(make=lambda img, i: _nan(img, i) if i == 2 else img.astype(np.float32)), ins),
        calib("raw series: one image of another size", "error", ("img_3.tif", "image is 80x60"),
              raw_series(make=lambda img, i: img[:60, :80].copy() if i == 2 else img)),
        calib("raw series: one image alone", "error", ("img_1.tif", "a single image"), raw_series(n=1)),
        calib("raw series: the folder is empty", "error", ("raw",), lambda r: (r / "raw").mkdir(), ins),
    ]
    return cases


def _recompress(path: Path, compression: str) -> None:
    """``path`` written again with ``compression``, its vendor tags' raw bytes kept."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages.first
        arr, extra = page.asarray(), []
        for code in (34118, 34682):
            if code in page.tags:
                tag = page.tags[code]
                tif.filehandle.seek(tag.valueoffset)
                extra.append((code, 2, 0, tif.filehandle.read(tag.valuebytecount).rstrip(b"\x00"), True))
    tifffile.imwrite(path, arr, compression=compression, metadata=None, extratags=extra)


def tiff_cases() -> list:
    """The TIFF rows (module docstring)."""
    return [*_views(), *_series()]

