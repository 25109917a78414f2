"""SEM vendor metadata: the parsers on documented text layouts, and real TIFF files written with tifffile."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from arcsem.errors import DataError
from arcsem.sem.image import read_sem_image
from arcsem.sem.metadata import parse_fei, parse_hitachi, parse_jeol, parse_tescan, parse_zeiss

# Zeiss SmartSEM tag 34118: KEY line, then "Label = value unit" (Latin-1: degree sign, micro sign)
ZEISS = ("0\r\n0\r\n5.824988e-009\r\nDP_SCAN_ROT\r\nScan Rot = On\r\nAP_WD\r\nWD =  3.9 mm\r\nAP_MAG\r\n"
         "Mag =  50.00 K X\r\nAP_SCANROTATION\r\nScan Rotation = 12.5 \u00b0\r\nAP_IMAGE_PIXEL_SIZE\r\n"
         "Image Pixel Size = 5.825 nm\r\nAP_WIDTH\r\nWidth = 5.965 \u00b5m\r\nDP_IMAGE_STORE\r\n"
         "Store resolution = 1024 * 768\r\nAP_STAGE_AT_T\r\nStage at T =  -9.0 \u00b0\r\nAP_STAGE_AT_R\r\n"
         "Stage at R = 245.8 \u00b0\r\n")
FEI = ("[User]\r\nDate=06/13/2016\r\n\r\n[Beam]\r\nBeam=EBeam\r\nScanRotation=0\r\n\r\n[EBeam]\r\nHFW=0.00172667\r\n"
       "WD=0.00403466\r\nTiltCorrectionIsOn=no\r\n\r\n[Scan]\r\nPixelWidth=3.3724e-006\r\n\r\n[Stage]\r\n"
       "StageR=-2.3611\r\nStageT=0.15707963\r\n\r\n[Image]\r\nResolutionY=442\r\nMagCanvasRealWidth=0.20720\r\n")
TESCAN = ("[MAIN]\r\nDevice=MIRA3\r\nMagnification=5000.0\r\nPixelSizeX=4.1e-008\r\nPixelSizeY=4.1e-008\r\n"
          "[SEM]\r\nScanRotation=0\r\nStageRotation=30.0\r\nStageTilt=12.5\r\nWD=0.0100\r\n")
HITACHI = ("[SemImageFile]\r\nInstructName=S-4800\r\nDataSize=1280x960\r\nPixelSize=9.921875\r\n"
           "Magnification=10000\r\nWorkingDistance=8100 um\r\n")
JEOL = "$CM_FORMAT JEOL/SEM\n$CM_MAG 5000\n$CM_FULL_SIZE 1280 960\n$$SM_MICRON_BAR 160\n$$SM_MICRON_MARKER 5um\n"


def test_zeiss_fields():
    m = parse_zeiss(ZEISS)
    assert (m.vendor, m.tilt_deg, m.rotation_deg) == ("zeiss", -9.0, 245.8)
    assert m.pixel_size_m == pytest.approx(5.825e-9)
    assert m.working_distance_m == pytest.approx(3.9e-3)
    assert m.magnification == pytest.approx(50_000)
    assert m.scan_rotation_deg == 12.5 and m.store_size == (1024, 768)
    assert m.field_width_m == pytest.approx(5.965e-6)
    assert m.missing == []


def test_zeiss_scan_rotation_off_and_missing_fields():
    m = parse_zeiss(ZEISS.replace("Scan Rot = On", "Scan Rot = Off").replace("Stage at T", "Stage goto T"))
    assert m.scan_rotation_deg is None
    assert m.missing == ["tilt_deg"]


def test_fei_radians_and_metres():
    m = parse_fei(FEI)
    assert m.tilt_deg == pytest.approx(9.0, abs=1e-6)            # 0.15707963 rad
    assert m.rotation_deg == pytest.approx(math.degrees(-2.3611))
    assert m.pixel_size_m == pytest.approx(3.3724e-6)
    assert m.image_rows == 442 and m.scan_rotation_deg is None
    assert m.magnification == pytest.approx(0.2072 / 0.00172667)  # 120 x, as the data bar shows


def test_fei_bad_numbers_are_missing():
    m = parse_fei(FEI.replace("PixelWidth=3.3724e-006", "PixelWidth=notafloat"))
    assert m.pixel_size_m is None and "pixel_size_m" in m.missing


def test_tescan_hitachi_jeol():
    t = parse_tescan(TESCAN)
    assert (t.tilt_deg, t.rotation_deg, t.pixel_size_m, t.working_distance_m) == (12.5, 30.0, 4.1e-8, 0.01)
    h = parse_hitachi(HITACHI)
    assert h.pixel_size_m == pytest.approx(9.921875e-9) and h.working_distance_m == pytest.approx(8.1e-3)
    assert h.tilt_deg is None and h.store_size == (1280, 960)
    j = parse_jeol(JEOL)
    assert j.pixel_size_m == pytest.approx(5e-6 / 160) and j.magnification == 5000 and j.tilt_deg is None


def _tif(path, data, tag=None, text="", extratags=()):
    import tifffile

    extra = [(tag, 2, 0, text.encode("latin-1"), True)] if tag else []
    tifffile.imwrite(path, data, extratags=[*extra, *extratags], metadata=None)
    return path


@pytest.mark.parametrize("tag,text,tilt", [(34118, ZEISS, -9.0), (34682, FEI, 9.0), (50431, TESCAN, 12.5)])
def test_tiff_tags_round_trip(tmp_path, tag, text, tilt):
    img = (np.arange(48 * 64).reshape(48, 64) % 251).astype(np.uint8)
    im = read_sem_image(_tif(tmp_path / "a.tif", img, tag, text))
    assert im.meta.tilt_deg == pytest.approx(tilt, abs=1e-6)
    np.testing.assert_array_equal(im.pixels, img)


def test_sixteen_bit_and_orientation(tmp_path):
    img = np.random.default_rng(0).integers(0, 65535, size=(30, 40), dtype=np.uint16)
    im = read_sem_image(_tif(tmp_path / "o.tif", img, extratags=[(274, 3, 1, 3, True)]))  # rotated 180
    assert im.bits == 16 and im.orientation == 3
    np.testing.assert_array_equal(im.pixels, img[::-1, ::-1])


def test_sidecars(tmp_path):
    import cv2

    img = np.full((20, 30), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "h.png"), img)
    (tmp_path / "h.txt").write_bytes(("\ufeff" + HITACHI).encode("utf-16-le"))  # Hitachi writes UTF-16
    cv2.imwrite(str(tmp_path / "t.png"), img)
    (tmp_path / "t.hdr").write_text(TESCAN)
    cv2.imwrite(str(tmp_path / "j.jpg"), img)
    (tmp_path / "j.txt").write_text(JEOL)
    assert read_sem_image(tmp_path / "h.png").meta.vendor == "hitachi"
    assert read_sem_image(tmp_path / "t.png").meta.tilt_deg == 12.5
    assert read_sem_image(tmp_path / "j.jpg").meta.vendor == "jeol"
    cv2.imwrite(str(tmp_path / "none.png"), img)
    m = read_sem_image(tmp_path / "none.png").meta
    assert m.vendor == "none" and m.missing == ["tilt_deg", "rotation_deg", "pixel_size_m"]


LOSSLESS = ("lzw", "adobe_deflate", "packbits", "zstd", "lzma")


@pytest.mark.parametrize("compression", [*LOSSLESS, "jpeg"])
def test_every_tiff_compression_reads_in_both_readers(tmp_path, compression):
    """SEM software writes LZW (Zeiss, by default), Deflate, PackBits, JPEG-in-TIFF, ZSTD: the calibration reader and
    the dataset reader both read each (tifffile with imagecodecs; OpenCV's own TIFF support lacks ZSTD and LZMA)."""
    import tifffile

    from arcsem.data.io import read_image

    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, size=(48, 64), dtype=np.uint8) if compression == "jpeg" else \
        rng.integers(0, 65536, size=(48, 64), dtype=np.uint16)
    path = tmp_path / f"{compression}.tif"
    tifffile.imwrite(path, img, compression=compression, metadata=None,
                     extratags=[(34118, 2, 0, ZEISS.encode("latin-1"), True)])
    im = read_sem_image(path)
    got, _ = read_image(path)
    assert im.meta.vendor == "zeiss" and im.meta.tilt_deg == -9.0
    scale = 255.0 if img.dtype == np.uint8 else 65535.0
    if compression in LOSSLESS:
        np.testing.assert_array_equal(im.pixels, img)
        np.testing.assert_array_equal(got, np.repeat((img / scale).astype(np.float32)[..., None], 3, -1))
    else:  # lossy: within the codec's error of the original, alike in both readers
        assert np.abs(im.pixels.astype(int) - img).mean() < 20
        np.testing.assert_allclose(got[..., 0], im.pixels / scale, atol=1e-6)


def test_tiled_and_multi_page_tiffs(tmp_path):
    import tifffile

    from arcsem.data.io import read_image

    img = (np.arange(40 * 56).reshape(40, 56) % 251).astype(np.uint8)
    tifffile.imwrite(tmp_path / "tiled.tif", img, tile=(16, 16), compression="lzw", metadata=None)
    np.testing.assert_array_equal(read_sem_image(tmp_path / "tiled.tif").pixels, img)
    with tifffile.TiffWriter(tmp_path / "pages.tif") as w:
        w.write(img, metadata=None)
        w.write(255 - img, metadata=None)
    im = read_sem_image(tmp_path / "pages.tif")
    np.testing.assert_array_equal(im.pixels, img)
    assert "2 pages: the first is used" in im.notes
    np.testing.assert_array_equal(read_image(tmp_path / "pages.tif")[0][..., 0], img / np.float32(255))


def test_a_tiff_codec_missing_says_what_to_install(tmp_path, monkeypatch):
    import tifffile

    tifffile.imwrite(tmp_path / "z.tif", np.zeros((8, 8), np.uint8), compression="zstd", metadata=None)
    real = tifffile.TiffPage.asarray

    def no_codec(self, *a, **k):
        raise ValueError("<COMPRESSION.ZSTD: 50000> requires the 'imagecodecs' package")
    monkeypatch.setattr(tifffile.TiffPage, "asarray", no_codec)
    with pytest.raises(DataError, match=r"z\.tif: cannot read TIFF .*requires the 'imagecodecs' package; install "
                                        r"it with pip install imagecodecs"):
        read_sem_image(tmp_path / "z.tif")
    monkeypatch.setattr(tifffile.TiffPage, "asarray", real)


@pytest.mark.parametrize("stored,expect_nm,note", [
    ((1024, 768), 5.825, None),                    # as scanned
    ((768, 1024), 5.825, "stored turned by 90 degrees"),  # stored upright: turned, not resized
    ((512, 384), 11.65, "resized after acquisition"),     # half the scan: pixels twice as large
])
def test_pixel_size_of_a_turned_or_resized_image(tmp_path, stored, expect_nm, note):
    """Zeiss records the scan (Store resolution 1024 x 768, 5.825 nm): an image stored a quarter turn from it keeps
    its pixel size (read before as resized, 1.33x too large), one stored at half size has twice it."""
    from arcsem.sem.series import read_series

    w, h = stored
    rng = np.random.default_rng(0)
    for i, tilt in enumerate((-3.0, 0.0, 3.0)):
        text = ZEISS.replace("Stage at T =  -9.0", f"Stage at T =  {tilt}")
        _tif(tmp_path / f"v{i}.tif", rng.integers(20, 230, size=(h, w), dtype=np.uint8), 34118, text)
    s = read_series(tmp_path)
    assert s.pixel_sizes == pytest.approx([expect_nm * 1e-9] * 3, rel=1e-3)
    notes = " ".join(s.images[0].notes)
    assert (note in notes) if note else ("turned" not in notes and "resized" not in notes)


@pytest.mark.parametrize("stage,tilt,rot,unit", [
    ("StageR=-2.3611\r\nStageT=0.15707963", 9.0, math.degrees(-2.3611), "rad?"),  # radians (most xT versions)
    ("StageR=135\r\nStageT=52", 52.0, 135.0, "deg"),                              # degrees: StageT beyond pi/2
    ("StageR=200.5\r\nStageT=0.5", 0.5, 200.5, "deg"),                            # degrees: StageR beyond 2 pi
    ("StageR=10 deg\r\nStageT=1.2 deg", 1.2, 10.0, "deg"),                        # the unit written
    ("StageR=0.5 rad\r\nStageT=0.1 rad", math.degrees(0.1), math.degrees(0.5), "rad"),
])
def test_fei_stage_angles_in_radians_or_degrees(stage, tilt, rot, unit):
    """FEI writes StageT/StageR in radians in some versions and degrees in others: 52 was read as 52 rad (2979 deg)."""
    m = parse_fei(FEI.replace("StageR=-2.3611\r\nStageT=0.15707963", stage))
    assert (m.tilt_deg, m.rotation_deg, m.angle_unit) == (pytest.approx(tilt), pytest.approx(rot), unit)
    assert m.origin("tilt_deg") == f"TIFF tag 34682 '[Stage] StageT ({'degrees' if unit == 'deg' else 'radians'})'"


def test_fei_series_reads_open_angles_as_degrees_with_the_rest(tmp_path):
    """A degrees series whose first tilt (1 deg) would also fit radians (57.3 deg): read as the series is written."""
    from arcsem.sem.series import read_series

    img = np.random.default_rng(0).integers(20, 230, size=(48, 64), dtype=np.uint8)
    for i, t in enumerate((1.0, 30.0, 60.0)):
        _tif(tmp_path / f"f{i}.tif", img, 34682, FEI.replace("StageR=-2.3611\r\nStageT=0.15707963",
                                                               f"StageR=0\r\nStageT={t}"))
    s = read_series(tmp_path)
    assert s.tilts == pytest.approx([1.0, 30.0, 60.0])
    assert "StageT/StageR read as degrees (as f1.tif, whose angles are in degrees)" in s.images[0].meta.notes
    assert set(s.sources["tilt"]) == {"TIFF tag 34682 '[Stage] StageT (degrees)'"}


@pytest.mark.parametrize("old,new,key", [
    ("Stage at T =  -9.0", "Stage at T =  -900.0", "'Stage at T = -900.0 \u00b0' gives -900 degrees"),   # x100
    ("Image Pixel Size = 5.825 nm", "Image Pixel Size = -5.825 nm", "'Image Pixel Size = -5.825 nm'"),
    ("Image Pixel Size = 5.825 nm", "Image Pixel Size = inf nm", "'Image Pixel Size = inf nm' gives inf m"),
    ("Stage at R = 245.8", "Stage at R = 24580", "'Stage at R = 24580 \u00b0'"),
])
def test_unphysical_vendor_values_are_refused_naming_file_and_key(tmp_path, old, new, key):
    """A Zeiss tag with tilts x100 or a negative pixel size was accepted (a negative focal length followed)."""
    from arcsem.errors import DataError
    from arcsem.sem.series import read_series

    img = np.random.default_rng(0).integers(20, 230, size=(48, 64), dtype=np.uint8)
    for i in range(2):
        _tif(tmp_path / f"z{i}.tif", img, 34118, ZEISS.replace(old, new))
    with pytest.raises(DataError, match=rf"z0\.tif: TIFF tag 34118 \(Zeiss\) {re.escape(key)}"):
        read_series(tmp_path)
    table = read_series(tmp_path, strict=False)                    # the inspection table shows it instead
    assert any(n.startswith("refused: TIFF tag 34118") for n in table.images[0].notes)
    (tmp_path.parent / "t.csv").write_text("z0.tif,0,10\nz1.tif,3,10\n")               # tilt and rotation
    overrides = {"tilts": str(tmp_path.parent / "t.csv")} if "Stage" in old else {"pixel_size_um": 0.01}
    assert read_series(tmp_path, **overrides).images[0].meta.vendor == "zeiss"   # an override replaces it
