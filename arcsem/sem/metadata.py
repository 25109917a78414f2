"""Vendor metadata of SEM images: stage tilt and rotation, pixel size, working distance, magnification.

Each parser is a pure function of the metadata text and returns a :class:`SemMeta` (angles in degrees,
lengths in metres); ``missing`` lists what the text did not give. Formats (docs/calibration.md says on
what evidence each is supported):

* **Zeiss SmartSEM**, TIFF tag 34118: a text block of ``KEY\\r\\nLabel = value unit`` pairs (Latin-1):
  ``Stage at T``, ``Stage at R`` (degrees), ``Image Pixel Size`` (pm/nm/µm/mm; else the field ``Width``
  over the image width: ``Pixel Size`` refers to the display, not the stored image), ``WD``, ``Mag``
  (``50.00 K X``), ``Store resolution`` (``1024 * 768``), ``Scan Rotation`` with ``Scan Rot = On|Off``,
  ``Tilt Corrn.`` / ``Tilt Angle`` (tilt correction stretches the image: warned);
* **FEI / Thermo Fisher xT**, TIFF tag 34682: an INI block; ``[Stage] StageT, StageR`` (radians in most
  versions, degrees in others: a unit written after the number decides, else the range: ``|StageT| > pi/2``
  or ``|StageR| > 2 pi`` cannot be radians; values that fit both are read as radians, ``angle_unit`` "rad?",
  and :func:`arcsem.sem.series.read_series` reads them as degrees when another image of the series is),
  ``[Scan] PixelWidth`` (metres), ``[Beam] ScanRotation`` (radians), ``[EBeam] WD`` (metres),
  ``[Image] ResolutionY`` (rows above the data bar), ``[EBeam] TiltCorrectionIsOn``;
* **TESCAN**, TIFF tag 50431 or an ``<image>.hdr`` sidecar: INI ``[MAIN] PixelSizeX`` (metres),
  ``Magnification``; ``[SEM] StageTilt, StageRotation, ScanRotation`` (degrees), ``WD`` (metres);
* **Hitachi**, ``<image>.txt`` sidecar with a ``[SemImageFile]`` section (ASCII or UTF-16):
  ``PixelSize`` (nm), ``Magnification``, ``WorkingDistance`` (``8100 um``), ``DataSize``; no stage tilt
  key is documented in the sources found, so tilts come from ``--tilts``;
* **JEOL**, ``<image>.txt`` sidecar of ``$CM_...`` / ``$$SM_...`` lines: pixel size from
  ``$$SM_MICRON_MARKER`` (``5um``) over ``$$SM_MICRON_BAR`` (pixels), ``$CM_MAG``, ``$CM_FULL_SIZE``; no
  stage tilt key documented: ``--tilts``.

``keys`` records which key gave each field (the inspection table's sources); :func:`problem` checks a value
against its physical range (the calibration refuses a negative pixel size or a tilt beyond 90 degrees, naming
the key). A key whose text is no number is missing; ``inf`` or ``nan`` written as a value is a problem.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

__all__ = ["FIELDS", "LIMITS", "SemMeta", "parse_fei", "parse_hitachi", "parse_jeol", "parse_tescan", "parse_zeiss",
           "problem"]

FIELDS = ("tilt_deg", "rotation_deg", "pixel_size_m")  # what calibration needs; others are informative
VENDORS = {"zeiss": "Zeiss", "fei": "FEI", "tescan": "TESCAN", "hitachi": "Hitachi", "jeol": "JEOL"}
# field -> (lowest, highest, unit, what is physical): vendor values outside are refused where they are used
LIMITS = {"tilt_deg": (-90.0, 90.0, "degrees", "a stage tilt lies within -90..90 degrees"),
          "rotation_deg": (-360.0, 360.0, "degrees", "a stage rotation lies within -360..360 degrees"),
          "pixel_size_m": (1e-12, 1e-3, "m", "a pixel size lies between 1 pm and 1 mm"),
          "field_width_m": (1e-10, 1.0, "m", "a field width lies between 0.1 nm and 1 m")}

_LENGTH = {"fm": 1e-15, "pm": 1e-12, "nm": 1e-9, "um": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0}
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|(?<![A-Za-z])[-+]?(?:inf(?:inity)?|nan)\b", re.IGNORECASE)


@dataclass
class SemMeta:
    """What a microscope wrote about one image (None where it wrote nothing usable).

    Attributes:
        vendor: ``zeiss | fei | tescan | hitachi | jeol | none``; ``source``: where it was read.
        tilt_deg, rotation_deg: stage tilt and rotation; ``scan_rotation_deg``: beam scan rotation
            (None when off).
        pixel_size_m: pixel size of the stored image in metres; ``working_distance_m``; ``magnification``.
        field_width_m: the scanned field's width in metres (gives the pixel size where none is written).
        store_size: ``(w, h)`` the microscope stored (Zeiss ``Store resolution``) or None.
        image_rows: rows of the image above a data bar (FEI ``ResolutionY``), or None.
        warnings: what makes the image unfit for an orthographic model (tilt correction on, ...).
        keys: field -> ``(key, text)``: the metadata key that gave it and its text as written.
        angle_unit: how the stage angles were written: ``deg``, ``rad``, or ``rad?`` (FEI: radians assumed).
        notes: how the text was read (the inspection table shows them).
    """

    vendor: str = "none"
    source: str = ""
    tilt_deg: float | None = None
    rotation_deg: float | None = None
    scan_rotation_deg: float | None = None
    pixel_size_m: float | None = None
    working_distance_m: float | None = None
    magnification: float | None = None
    field_width_m: float | None = None
    store_size: tuple[int, int] | None = None
    image_rows: int | None = None
    warnings: list[str] = field(default_factory=list)
    keys: dict[str, tuple[str, str]] = field(default_factory=dict)
    angle_unit: str = "deg"
    notes: list[str] = field(default_factory=list)

    @property
    def missing(self) -> list[str]:
        """The calibration fields (:data:`FIELDS`) this image lacks."""
        return [f for f in FIELDS if getattr(self, f) is None]

    def origin(self, name: str) -> str:
        """Where field ``name`` came from: ``TIFF tag 34118 'Stage at T'`` (or the source alone)."""
        key = self.keys.get(name)
        return f"{self.source} '{key[0]}'" if key else self.source

    def note_keys(self, pairs: dict[str, tuple[str, str | None]]) -> None:
        """Record ``{field: (key, text)}`` in :attr:`keys` for the fields that got a value."""
        self.keys.update({f: (k, t) for f, (k, t) in pairs.items() if t is not None and getattr(self, f) is not None})

    def angles_in_degrees(self, why: str) -> None:
        """Read stage angles taken as radians (``angle_unit`` "rad?") as degrees instead, noting ``why``."""
        if self.angle_unit != "rad?":
            return
        self.tilt_deg, self.rotation_deg = (None if v is None else math.radians(v)
                                            for v in (self.tilt_deg, self.rotation_deg))
        self.angle_unit = "deg"
        self.keys.update({f: (k.replace("(radians)", "(degrees)"), t) for f, (k, t) in self.keys.items()})
        self.notes.append(f"StageT/StageR read as degrees ({why})")


def problem(meta: SemMeta, name: str) -> str | None:
    """Why field ``name`` of ``meta`` is not physical (:data:`LIMITS`; NaN and infinity included), or None."""
    value = getattr(meta, name)
    lo, hi, unit, rule = LIMITS[name]
    if value is None or lo <= value <= hi:
        return None
    key, text = meta.keys.get(name, (name, f"{value:g}"))
    return f"{meta.source} ({VENDORS.get(meta.vendor, meta.vendor)}) '{key} = {text}' gives {value:g} {unit}, but {rule}"


def _number(text: str | None) -> float | None:
    """The first number in ``text`` (``inf`` and ``nan`` included); None without one."""
    if text is None:
        return None
    m = _NUMBER.search(text)
    return None if m is None else float(m.group())


def _length(text: str | None, default_unit: str | None = None) -> float | None:
    """``'5.825 nm'`` -> 5.825e-9 m; the unit follows the number (``default_unit`` when there is none)."""
    if text is None:
        return None
    m = _NUMBER.search(text)
    if m is None:
        return None
    unit = text[m.end():].strip().split(" ")[0] if text[m.end():].strip() else default_unit
    factor = _LENGTH.get((unit or "").replace("\u00b5", "u").replace("\u03bc", "u"))  # micro sign, Greek mu
    return float(m.group()) * factor if factor is not None else None


def _magnification(text: str | None) -> float | None:
    """``'50.00 K X'`` -> 50000; ``'105 X'`` -> 105."""
    value = _number(text)
    if value is None:
        return None
    return value * 1000.0 if re.search(r"\d\s*[kK]\s*[xX]?", text) else value


def zeiss_pairs(text: str) -> dict[str, str]:
    """``Label = value`` lines of a Zeiss block -> ``{label: value}`` (the first occurrence wins)."""
    pairs: dict[str, str] = {}
    for line in re.split(r"\r\n|\n|\r", text):
        if " = " in line:
            key, _, value = line.partition(" = ")
            pairs.setdefault(key.strip(), value.strip())
    return pairs


def _finite(value: float | None) -> float | None:
    """``value`` when finite (informative fields: working distance, magnification), else None."""
    return value if value is not None and math.isfinite(value) else None


def parse_zeiss(text: str, source: str = "TIFF tag 34118") -> SemMeta:
    """Zeiss SmartSEM metadata (see the module docstring)."""
    p = zeiss_pairs(text)
    meta = SemMeta(vendor="zeiss", source=source, tilt_deg=_number(p.get("Stage at T")),
                   rotation_deg=_number(p.get("Stage at R")), working_distance_m=_finite(_length(p.get("WD"))),
                   magnification=_finite(_magnification(p.get("Mag"))))
    meta.pixel_size_m, meta.field_width_m = _length(p.get("Image Pixel Size")), _length(p.get("Width"))
    meta.note_keys({f: (k, p.get(k)) for f, k in (("tilt_deg", "Stage at T"), ("rotation_deg", "Stage at R"),
                   ("pixel_size_m", "Image Pixel Size"), ("field_width_m", "Width"), ("working_distance_m", "WD"),
                   ("magnification", "Mag"))})
    if (p.get("Scan Rot") or "").lower() == "on":
        meta.scan_rotation_deg = _finite(_number(p.get("Scan Rotation")))
    size = re.findall(r"\d+", p.get("Store resolution", ""))
    if len(size) == 2:
        meta.store_size = (int(size[0]), int(size[1]))
    if (p.get("Tilt Corrn.") or "").lower() == "on" and abs(_finite(_number(p.get("Tilt Angle"))) or 0.0) > 0:
        meta.warnings.append(f"tilt correction on (Tilt Angle = {p.get('Tilt Angle')}): the image is stretched")
    return meta


def ini_sections(text: str) -> dict[str, dict[str, str]]:
    """An INI text -> ``{section: {key: value}}``; lines before any section go to section ``''``."""
    out: dict[str, dict[str, str]] = {"": {}}
    section = ""
    for line in re.split(r"\r\n|\n|\r", text):
        line = line.strip().strip("\x00")
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1].strip()
            out.setdefault(section, {})
        elif "=" in line:
            key, _, value = line.partition("=")
            out.setdefault(section, {}).setdefault(key.strip(), value.strip())
    return out


def _fei_angle_unit(t_text: str | None, r_text: str | None) -> tuple[str, str]:
    """How FEI wrote ``StageT``/``StageR`` (module docstring): ``(unit, why)``, unit ``deg | rad | rad?``."""
    written = f"{t_text or ''} {r_text or ''}".lower()
    if "deg" in written or "\u00b0" in written:
        return "deg", "a degree unit is written"
    if "rad" in written:
        return "rad", "a radian unit is written"
    t, r = _number(t_text), _number(r_text)
    if t is not None and math.isfinite(t) and abs(t) > math.pi / 2 + 1e-6:
        return "deg", f"StageT = {t_text} is beyond pi/2, so not radians"
    if r is not None and math.isfinite(r) and abs(r) > 2 * math.pi + 1e-6:
        return "deg", f"StageR = {r_text} is beyond 2 pi, so not radians"
    return "rad?", ""


def parse_fei(text: str, source: str = "TIFF tag 34682") -> SemMeta:
    """FEI / Thermo Fisher xT metadata (see the module docstring)."""
    ini = ini_sections(text)
    stage, scan, beam, image = (ini.get(k, {}) for k in ("Stage", "Scan", "Beam", "Image"))
    ebeam = ini.get(beam.get("Beam", "EBeam"), {}) or ini.get("EBeam", {})
    unit, why = _fei_angle_unit(stage.get("StageT"), stage.get("StageR"))
    angle = (lambda v: v) if unit == "deg" else math.degrees
    t, r = _number(stage.get("StageT")), _number(stage.get("StageR"))
    meta = SemMeta(vendor="fei", source=source, tilt_deg=None if t is None else angle(t),
                   rotation_deg=None if r is None else angle(r), pixel_size_m=_number(scan.get("PixelWidth")),
                   working_distance_m=_finite(_number(ebeam.get("WD") or stage.get("WorkingDistance"))),
                   angle_unit=unit)
    if why:
        meta.notes.append(f"StageT/StageR read as {'degrees' if unit == 'deg' else 'radians'} ({why})")
    scan_rot = _finite(_number(beam.get("ScanRotation")))
    meta.scan_rotation_deg = math.degrees(scan_rot) if scan_rot else None
    rows = _finite(_number(image.get("ResolutionY")))
    meta.image_rows = int(rows) if rows and rows > 0 else None
    width, hfw = _finite(_number(image.get("MagCanvasRealWidth"))), _number(ebeam.get("HFW") or scan.get("HorFieldsize"))
    meta.field_width_m = hfw
    if width and hfw and math.isfinite(hfw):
        meta.magnification = width / hfw
    written = "degrees" if unit == "deg" else "radians"
    meta.note_keys({"tilt_deg": (f"[Stage] StageT ({written})", stage.get("StageT")),
                    "rotation_deg": (f"[Stage] StageR ({written})", stage.get("StageR")),
                    "pixel_size_m": ("[Scan] PixelWidth", scan.get("PixelWidth")),
                    "field_width_m": ("HFW", ebeam.get("HFW") or scan.get("HorFieldsize")),
                    "working_distance_m": ("WD", ebeam.get("WD") or stage.get("WorkingDistance")),
                    "magnification": ("MagCanvasRealWidth / HFW", image.get("MagCanvasRealWidth"))})
    if (ebeam.get("TiltCorrectionIsOn") or "").lower() in ("yes", "on", "true"):
        meta.warnings.append("tilt correction on: the image is stretched")
    return meta


def parse_tescan(text: str, source: str = "TIFF tag 50431") -> SemMeta:
    """TESCAN metadata, embedded or ``.hdr`` sidecar (section headers optional; see the module docstring)."""
    flat: dict[str, str] = {}
    for section in ini_sections(text).values():
        for k, v in section.items():
            flat.setdefault(k, v)
    scan_rot = _finite(_number(flat.get("ScanRotation")))
    meta = SemMeta(vendor="tescan", source=source, tilt_deg=_number(flat.get("StageTilt")),
                   rotation_deg=_number(flat.get("StageRotation")), pixel_size_m=_number(flat.get("PixelSizeX")),
                   working_distance_m=_finite(_number(flat.get("WD"))),
                   magnification=_finite(_number(flat.get("Magnification"))),
                   scan_rotation_deg=scan_rot if scan_rot else None)
    meta.note_keys({f: (k, flat.get(k)) for f, k in (("tilt_deg", "StageTilt"), ("rotation_deg", "StageRotation"),
                   ("pixel_size_m", "PixelSizeX"), ("working_distance_m", "WD"), ("magnification", "Magnification"))})
    return meta


def parse_hitachi(text: str, source: str = "Hitachi .txt sidecar") -> SemMeta:
    """Hitachi ``[SemImageFile]`` sidecar (see the module docstring)."""
    sec = ini_sections(text).get("SemImageFile", {})
    pixel_nm = _number(sec.get("PixelSize"))
    size = re.findall(r"\d+", sec.get("DataSize", ""))
    meta = SemMeta(vendor="hitachi", source=source, pixel_size_m=None if pixel_nm is None else pixel_nm * 1e-9,
                   magnification=_finite(_number(sec.get("Magnification"))),
                   working_distance_m=_finite(_length(sec.get("WorkingDistance"), "um")),
                   store_size=(int(size[0]), int(size[1])) if len(size) == 2 else None)
    meta.note_keys({f: (k, sec.get(k)) for f, k in (("pixel_size_m", "PixelSize"), ("magnification", "Magnification"),
                                                    ("working_distance_m", "WorkingDistance"))})
    return meta


def parse_jeol(text: str, source: str = "JEOL .txt sidecar") -> SemMeta:
    """JEOL ``$CM_`` / ``$$SM_`` sidecar (see the module docstring)."""
    keys: dict[str, str] = {}
    for line in re.split(r"\r\n|\n|\r", text):
        parts = line.strip().split(None, 1)
        if len(parts) == 2 and parts[0].startswith("$"):
            keys.setdefault(parts[0].lstrip("$"), parts[1].strip())
    bar_px, marker = _number(keys.get("SM_MICRON_BAR")), _length(keys.get("SM_MICRON_MARKER"))
    size = re.findall(r"\d+", keys.get("CM_FULL_SIZE", ""))
    meta = SemMeta(vendor="jeol", source=source, magnification=_finite(_number(keys.get("CM_MAG"))),
                   pixel_size_m=marker / bar_px if marker is not None and bar_px else None,
                   store_size=(int(size[0]), int(size[1])) if len(size) == 2 else None)
    text = f"{keys.get('SM_MICRON_MARKER')} / {keys.get('SM_MICRON_BAR')} px"
    meta.note_keys({"pixel_size_m": ("$$SM_MICRON_MARKER / $$SM_MICRON_BAR", text),
                    "magnification": ("$CM_MAG", keys.get("CM_MAG"))})
    return meta
