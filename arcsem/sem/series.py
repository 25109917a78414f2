"""A folder of SEM images as one series: one size, one crop, per-view stage angles and pixel size.

Images are the folder's ``.tif .tiff .png .jpg .jpeg .bmp`` files in natural order (``img_2`` before
``img_10``). Stage angles come from the vendor metadata, or from ``tilts``: a list of numbers (one per
image, in that order) or a CSV file with columns ``file, tilt[, rotation]`` (degrees; a header line is
optional; ``file`` is the image's name or stem). The pixel size (metres) comes from the metadata (scaled
when the image was resized after acquisition: Zeiss ``Store resolution``) or ``pixel_size_um``.

Vendor values that are used are checked against their physical range (:func:`arcsem.sem.metadata.problem`): a
tilt beyond 90 degrees, a rotation beyond a turn, a pixel size that is not positive and finite stop the series
with a DataError naming the file and the key (the inspection table shows them instead). FEI stage angles whose
unit the values leave open are read as degrees when another FEI image of the series is certainly in degrees.
Every number keeps where it came from (``Series.sources``; the inspection table lists them).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..names import view_names
from .crop import Crop, detect_crop
from .image import IMAGE_SUFFIXES, SemImage, read_sem_image
from .metadata import problem

__all__ = ["Series", "inspect_table", "list_images", "parse_tilts", "read_series"]


@dataclass
class Series:
    """An SEM series ready for calibration.

    Attributes:
        folder: the input folder; ``images``: the views (uncropped pixels), ``names``: their view names.
        crop: the crop every image gets; ``tilts`` / ``rotations``: stage angles in degrees (None when
            unknown), ``angle_source``: where they came from (the series); ``pixel_sizes``: metres per pixel
            (None when unknown); ``sources``: per quantity (``tilt``, ``rotation``, ``pixel``) per image where
            its value came from; ``notes``: series-level remarks for the report.
    """

    folder: Path
    images: list[SemImage]
    names: list[str]
    crop: Crop
    tilts: list[float | None]
    rotations: list[float | None]
    angle_source: str
    pixel_sizes: list[float | None]
    notes: list[str] = field(default_factory=list)
    sources: dict[str, list[str]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.images)

    def pixels(self, i: int) -> np.ndarray:
        """The cropped pixels of view ``i`` ``[h, w]`` (uint8/uint16)."""
        return self.crop.apply(self.images[i].pixels)

    @property
    def size(self) -> tuple[int, int]:
        """Cropped ``(w, h)``."""
        return self.crop.size(*self.images[0].size)

    @property
    def pixel_size_m(self) -> float | None:
        """The series' pixel size (median of the known ones), or None."""
        known = [p for p in self.pixel_sizes if p]
        return float(np.median(known)) if known else None


def _natural_key(path: Path) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def list_images(folder: Path) -> list[Path]:
    """The image files of ``folder`` in natural order (DataError if there is no folder or no image)."""
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder")
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                    and not p.name.startswith(".")), key=_natural_key)
    if not files:
        raise DataError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return files


def _float(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{where}: '{text}' is not a number") from None
    if not np.isfinite(value):
        raise DataError(f"{where}: '{text}' is not a finite number")
    return value


def parse_tilts(spec: str, files: list[Path]) -> tuple[list[float], list[float | None], str]:
    """``--tilts``: a comma list or a CSV file -> per-file tilts, rotations (None if not given), source."""
    path = Path(spec)
    if not path.is_file():
        values = [v for v in re.split(r"[,\s;]+", spec.strip()) if v]
        tilts = [_float(v, "--tilts") for v in values]
        if len(tilts) != len(files):
            raise DataError(f"--tilts has {len(tilts)} value(s) but {files[0].parent} holds {len(files)} images")
        return tilts, [None] * len(files), "--tilts list"
    rows = [re.split(r"\s*[,;\t]\s*|\s+", line.strip()) for line in path.read_text().splitlines()]
    rows = [r for r in rows if r and r[0] and not r[0].startswith("#")]
    if rows and len(rows[0]) > 1 and not re.fullmatch(r"[-+]?[\d.eE+-]+", rows[0][1]):
        rows = rows[1:]  # header line
    by_name: dict[str, tuple[float, float | None]] = {}
    for n, row in enumerate(rows, 1):
        if len(row) < 2:
            raise DataError(f"{path}: row {n} needs 'file, tilt[, rotation]', got {','.join(row)}")
        where = f"{path}: row {n} ({row[0]})"
        by_name[row[0]] = (_float(row[1], where), _float(row[2], where) if len(row) > 2 else None)
    keys = {f: next((k for k in (f.name, f.stem) if k in by_name), None) for f in files}
    missing = [f.name for f, k in keys.items() if k is None]
    if missing:
        raise DataError(f"{path}: no tilt for image {missing[0]} ({len(missing)} of {len(files)} images missing)")
    unknown = sorted(set(by_name) - set(keys.values()))
    if unknown:
        raise DataError(f"{path}: '{unknown[0]}' is not an image of {files[0].parent}")
    return [by_name[keys[f]][0] for f in files], [by_name[keys[f]][1] for f in files], f"--tilts {path.name}"


def _pixel_size(im: SemImage) -> tuple[float | None, str]:
    """The image's pixel size in metres and where it came from, scaled when it was stored at another resolution
    than it has; an image stored a quarter turn from the scan (the metadata's width and height swapped) keeps it:
    it was turned, not resized (a Zeiss series stored upright, 1536 x 2048 from a 2048 x 1536 scan)."""
    m = im.meta
    p, (w, h), store, src = m.pixel_size_m, im.size, m.store_size, m.origin("pixel_size_m")
    turned = store is not None and store != (w, h) and store == (h, w)
    if turned:
        im.notes.append(f"stored turned by 90 degrees from the scan ({store[0]} x {store[1]} scanned, {w} x {h} "
                        "stored): pixel size kept")
    if p is None and m.field_width_m:
        p = m.field_width_m / (h if turned else w)  # the field width runs along the scan lines
        src = f"{m.origin('field_width_m')} / {h if turned else w} px"
        im.notes.append(f"pixel size = field width / the scan lines' {'height' if turned else 'width'} in pixels")
    elif p and store and not turned and store[0] != w:
        p, src = p * store[0] / w, f"{src} x {store[0]} / {w} px"
        im.notes.append(f"resized after acquisition ({store[0]} -> {w} px wide): pixel size scaled")
    return p, (src if p is not None else "none")


def _fei_units(images: list[SemImage]) -> None:
    """FEI stage angles that fit radians and degrees (``rad?``) read as degrees when another FEI image of the series
    is certainly in degrees (one microscope, one software version)."""
    sure = next((im for im in images if im.meta.vendor == "fei" and im.meta.angle_unit == "deg"), None)
    if sure is not None:
        for im in images:
            im.meta.angles_in_degrees(f"as {sure.path.name}, whose angles are in degrees")


def _check(im: SemImage, fields: tuple[str, ...], fix: str, strict: bool) -> None:
    """Refuse (``strict``: DataError naming the file and the key) or note the unphysical values of ``fields``."""
    for name in fields:
        why = problem(im.meta, name)
        if why and strict:
            raise DataError(f"{im.path}: {why}; {fix}")
        if why:
            im.notes.append(f"refused: {why}")


def _angles(images: list[SemImage], files: list[Path], tilts: str | None, strict: bool):
    """Per image tilt and rotation (degrees or None), the series' angle source and per image sources."""
    _fei_units(images)
    if tilts is not None:
        tilt, rot, source = parse_tilts(tilts, files)
        for r, im in zip(rot, images):
            _check(im, ("rotation_deg",) if r is None else (), "give the rotation in the --tilts CSV", strict)
        rsrc = [source if r is not None else (im.meta.origin("rotation_deg") if im.meta.rotation_deg is not None
                                              else "default 0 (none given)") for r, im in zip(rot, images)]
        rot = [r if r is not None else (im.meta.rotation_deg or 0.0) for r, im in zip(rot, images)]
        return tilt, rot, source, [source] * len(images), rsrc
    for im in images:
        _check(im, ("tilt_deg", "rotation_deg"), "give --tilts (a list or a CSV) to override", strict)
    tilt, rot = [im.meta.tilt_deg for im in images], [im.meta.rotation_deg for im in images]
    vendors = sorted({im.meta.vendor for im in images if im.meta.tilt_deg is not None})
    src = [[im.meta.origin(f) if getattr(im.meta, f) is not None else "none" for im in images]
           for f in ("tilt_deg", "rotation_deg")]
    return tilt, rot, f"metadata ({', '.join(vendors)})" if vendors else "none", *src


def _pixel_sizes(images: list[SemImage], pixel_size_um: float | None, strict: bool):
    """Per image pixel size (metres or None) and where it came from."""
    if pixel_size_um is not None:
        if not np.isfinite(pixel_size_um) or pixel_size_um <= 0:
            raise DataError(f"--pixel-size {pixel_size_um:g}: must be a positive number of micrometres")
        return [pixel_size_um * 1e-6] * len(images), ["--pixel-size"] * len(images)
    for im in images:
        used = ("pixel_size_m",) if im.meta.pixel_size_m is not None else ("field_width_m",)
        _check(im, used, "give --pixel-size (micrometres) to override", strict)
    found = [_pixel_size(im) for im in images]
    return [p for p, _ in found], [s for _, s in found]


def read_series(folder: str | Path, tilts: str | None = None, pixel_size_um: float | None = None,
                crop_bottom: int | None = None, strict: bool = True) -> Series:
    """Read, check and crop the images of ``folder`` (see the module docstring); ``strict=False`` (for the
    inspection table) accepts images of several sizes and unphysical metadata, and crops none of them."""
    folder = Path(folder).expanduser().resolve()
    files = list_images(folder)
    images = [read_sem_image(f) for f in files]
    first = images[0]
    odd = next((im for im in images[1:] if im.size != first.size), None)
    if odd is not None and strict:
        raise DataError(f"{odd.path}: image is {odd.size[0]}x{odd.size[1]} but {first.path.name} is "
                        f"{first.size[0]}x{first.size[1]}; a series must share one image size")
    if odd is None:
        crop = detect_crop([im.pixels for im in images], [im.meta.image_rows for im in images], crop_bottom)
    else:
        crop = Crop(reasons=("images of several sizes: not a series",))
    w, h = crop.size(*first.size)
    if w < 32 or h < 32:
        raise DataError(f"{folder}: after cropping ({crop.describe()}) the images are {w}x{h}, too small")
    tilt, rot, source, tsrc, rsrc = _angles(images, files, tilts, strict)
    sizes, psrc = _pixel_sizes(images, pixel_size_um, strict)
    return Series(folder, images, view_names(files), crop, tilt, rot, source, sizes,
                  sources={"tilt": tsrc, "rotation": rsrc, "pixel": psrc})


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _by_source(label: str, sources: list[str], names: list[str]) -> str:
    """``label: source (every image)`` or ``label: source A (a.tif, b.tif); source B (c.tif)``."""
    groups: dict[str, list[str]] = {}
    for src, name in zip(sources, names):
        groups.setdefault(src, []).append(name)
    if len(groups) == 1:
        return f"  {label}: {sources[0]} (every image)"
    parts = [f"{src} ({', '.join(n[:3])}{f' and {len(n) - 3} more' if len(n) > 3 else ''})" for src, n in groups.items()]
    return f"  {label}: " + "; ".join(parts)


def _sources(series: Series) -> list[str]:
    """The table's footer: where each column's numbers came from, per group of images."""
    names = [im.path.name for im in series.images]
    meta = [im.meta for im in series.images]
    def origin(f):
        return [m.origin(f) if getattr(m, f) is not None else "none" for m in meta]
    orient = ["as stored" if im.orientation == 1 else f"TIFF/EXIF Orientation {im.orientation}" for im in series.images]
    levels = ["-" if im.levels is None else im.levels.describe() for im in series.images]
    rows = [("tilt", series.sources.get("tilt")), ("rot", series.sources.get("rotation")),
            ("pixel", series.sources.get("pixel")), ("levels", levels), ("WD", origin("working_distance_m")),
            ("mag", origin("magnification")), ("orient", orient)]
    return ["where the numbers come from:", *(_by_source(k, v, names) for k, v in rows if v)]


def inspect_table(series: Series) -> str:
    """One line per image: size, bits, vendor, tilt, rotation, pixel size, WD, mag, orientation, missing; then the
    crop, and where each column's numbers came from (metadata key, file, option or default)."""
    head = ("file", "size", "bits", "vendor", "tilt", "rot", "pixel", "WD mm", "mag", "orient", "missing / notes")
    rows = []
    for im, tilt, rot, px in zip(series.images, series.tilts, series.rotations, series.pixel_sizes):
        m = im.meta
        missing = [k for k, v in (("tilt", tilt), ("rotation", rot), ("pixel size", px)) if v is None]
        notes = ([f"no {', '.join(missing)}"] if missing else []) + m.warnings + m.notes + im.notes
        rows.append((im.path.name, f"{im.size[0]}x{im.size[1]}", str(im.bits), m.vendor, _fmt(tilt, ".2f"),
                     _fmt(rot, ".2f"), "-" if px is None else f"{px * 1e9:.4g} nm",
                     _fmt(None if m.working_distance_m is None else m.working_distance_m * 1e3, ".2f"),
                     _fmt(m.magnification, ".4g"), str(im.orientation), "; ".join(notes) or "-"))
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip()
    w, h = series.size
    mixed = len({im.size for im in series.images}) > 1
    foot = [f"crop (every image): {series.crop.describe()}" + ("" if mixed else f" -> {w}x{h}"),
            f"stage angles: {series.angle_source}; pixel size: "
            + ("unknown (world unit = one pixel)" if series.pixel_size_m is None
               else f"{series.pixel_size_m * 1e9:.4g} nm (world unit = 1 micrometre)")]
    return "\n".join([line(head), *(line(r) for r in rows), "", *foot, *_sources(series)])
