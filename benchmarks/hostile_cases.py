"""The hostile-input cases of issue 40 and around them, each with what arcsem must answer (benchmarks/hostile_inputs.py
runs them; tests/test_hostile_inputs.py runs each in CI).

A :class:`Case` writes or edits the tiny scene, adds overrides, and expects ``error`` (exit 2, one ``error:`` line
holding every needle), ``warning`` (exit 0, a logged warning holding every needle) or ``ok`` (exit 0, the needles
in the printed output or warnings, none of ``absent``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hostile_files import (
    bmp_declaring,
    colour_views,
    grey_views,
    jpeg_declaring,
    json_edit,
    json_text,
    png_declaring,
    rgba_views,
    symlink_loop,
)

__all__ = ["CASES", "TINY", "Case"]

TINY = ["train.width=null", "threads=1", "train.steps=3", "train.eval.video=false", "train.eval.lpips=false",
        "train.progress=false", "backbone.random_init_points=200", "colorize.steps=2", "colorize.progress=false",
        "colorize.eval.video=false", "colorize.eval.lpips=false", "mesh.enabled=false"]


@dataclass
class Case:
    """One hostile input and the answer it must get (module docstring)."""

    name: str
    expect: str = "error"  # error | warning | ok
    needles: tuple[str, ...] = ()
    write: Callable[[Path], list[str] | None] | None = None  # edits the scene folder; may return dataset overrides
    overrides: list[str] = field(default_factory=list)
    stage: str = "check"
    dataset: str = "transforms"  # or synthetic (no scene folder is read)
    absent: tuple[str, ...] = ()
    in_case_dir: bool = False  # run with the case folder as the working directory
    address_space_gb: float | None = None  # RLIMIT_AS above what the process uses while the case runs
    tool: str = "arcsem"  # or calibrate: arcsem-calibrate <scene>/raw --out <case>/run <overrides as arguments>


def _frame(**kw):
    return json_edit(lambda m: m["frames"][0].update(**kw))


def _top(**kw):
    return json_edit(lambda m: m.update(**kw))


def _path(rel: str):
    """Overrides whose dataset.path is ``rel`` inside the scene folder (written by the case)."""
    def write(root: Path) -> list[str]:
        return [f"dataset.path={root / rel}"]
    return write


def _both(*writers):
    def write(root: Path) -> list[str] | None:
        out = None
        for w in writers:
            ret = w(root)
            out = ret if isinstance(ret, list) else out
        return out
    return write


def _folder_named(name: str, reference: bool):
    """A folder ``name`` in the working directory (the case folder), holding a colour reference of view_01."""
    def write(root: Path) -> None:
        import cv2
        import numpy as np

        folder = root.parent / name
        folder.mkdir()
        if reference:
            img = np.zeros((24, 32, 3), np.uint8)
            img[..., 2] = 220
            cv2.imwrite(str(folder / "view_01.png"), img)
    return write


def _twelve_k(root: Path) -> None:
    for i in range(3):
        png_declaring(f"view_{i:02d}", 12000, 12000, rows=1)(root)
    json_edit(lambda m: (m.update(w=12000, h=12000), m["frames"].pop()))(root)


def _deep(opening: str, closing: str, depth: int = 200_000):
    return json_text(lambda _: (opening * depth + closing * depth).encode())


def _images() -> list[Case]:
    alpha0 = "an alpha channel that is 0 everywhere"
    return [
        Case("RGBA PNGs, alpha 0 everywhere", "warning", ("view_00.png and 3 more", alpha0), rgba_views(0)),
        Case("RGBA 16-bit PNGs, alpha 0 everywhere", "warning", (alpha0,), rgba_views(0, bits=16)),
        Case("grey+alpha PNGs, alpha 0 everywhere", "warning", (alpha0,), rgba_views(0, grey_alpha=True)),
        Case("one RGBA view with alpha 0, three with alpha 255", "error", ("view_01", "no mask"),
             _both(rgba_views(255), rgba_views(0, views=[1]))),
        Case("RGBA PNGs, alpha 255", "ok", ("masks",), rgba_views(255), absent=(alpha0,)),
        Case("RGB PNGs of grey content", "ok", ("check: OK",), grey_views(".png"), absent=("colour content",)),
        Case("colour JPEGs of grey content", "ok", ("check: OK",), grey_views(".jpg"), absent=("colour content",)),
        Case("grey JPEGs", "ok", ("check: OK",), grey_views(".jpg", colour_file=False), absent=("colour content",)),
        Case("grey BMPs", "ok", ("check: OK",), grey_views(".bmp", colour_file=False), absent=("colour content",)),
        Case("colour PNG views", "warning", ("view_00.png and 3 more", "colour content"), colour_views(".png")),
        Case("colour JPEG views", "warning", ("view_00.jpg", "colour content"), colour_views(".jpg")),
        Case("colour 16-bit PNG views", "warning", ("colour content",), colour_views(".png", bits=16)),
        Case("PNG declaring 40000x40000 px", "error", ("view_01.png", "declares 40000x40000 px"),
             png_declaring("view_01", 40000, 40000)),
        Case("PNG declaring 40000x40000 px, no w/h in the json", "error", ("view_01.png", "declares 40000x40000"),
             _both(png_declaring("view_01", 40000, 40000), json_edit(lambda m: (m.pop("w"), m.pop("h"))))),
        Case("JPEG declaring 65000x65000 px", "error", ("view_01.jpg", "declares 65000x65000 px"),
             jpeg_declaring(65000, 65000)),
        Case("BMP declaring 50000x50000 px", "error", ("view_01.bmp", "declares 50000x50000 px"),
             bmp_declaring(50000, 50000)),
        Case("PNG header 64x48 under a 32x24 camera", "error", ("view_01", "is 64x48 but its camera is 32x24"),
             png_declaring("view_01", 64, 48)),
        Case("three 12000x12000 views, 8 GB of address space", "error",
             ("3 view(s) of up to 12000x12000 px", "needs about 10.9 GB"), _twelve_k, address_space_gb=8),
        Case("mask PNG declaring 40000x40000 px", "error", ("m.png", "declares 40000x40000 px"),
             _both(png_declaring("m", 40000, 40000), _frame(mask_path="m.png"))),
        Case("zero-byte PNG", "error", ("view_01.png", "cannot read image"),
             lambda r: (r / "view_01.png").write_bytes(b"")),
        Case("text file named .png", "error", ("view_01.png", "cannot read image"),
             lambda r: (r / "view_01.png").write_text("not an image")),
        Case("truncated PNG", "error", ("view_01.png",),
             lambda r: (r / "view_01.png").write_bytes((r / "view_01.png").read_bytes()[:60])),
        Case("image is a symbolic link to itself", "error", ("view_01.png", "symbolic link that loops"),
             symlink_loop()),
        Case("image is a dangling symbolic link", "error", ("frame 1", "file not found"),
             lambda r: ((r / "view_01.png").unlink(), (r / "view_01.png").symlink_to(r / "gone.png"))),
        Case("image path is a folder", "error", ("frame 1", "file not found"),
             lambda r: ((r / "view_01.png").unlink(), (r / "view_01.png").mkdir())),
        Case("file_path holds a NUL", "error", ("NUL",), _frame(file_path="view\u0000.png")),
        Case("file_path a number", "error", ("frame 0", "file not found"), _frame(file_path=123)),
        Case("file_path escapes upwards", "error", ("file not found",), _frame(file_path="../../../../nope.png")),
    ]


def _json() -> list[Case]:
    return [
        Case("transforms.json in Latin-1", "error", ("transforms.json", "not UTF-8"),
             json_text(lambda t: t.replace('"w"', '"w\u00e9", "w"').encode("latin-1"))),
        Case("transforms.json in UTF-16", "error", ("transforms.json", "not UTF-8"),
             json_text(lambda t: t.encode("utf-16"))),
        Case("transforms.json with a UTF-8 BOM", "ok", ("check: OK",), json_text(lambda t: t.encode("utf-8-sig"))),
        Case("JSON arrays nested 200,000 deep", "error", ("transforms.json", "nested too deeply"), _deep("[", "]")),
        Case("JSON objects nested 100,000 deep", "error", ("transforms.json", "nested too deeply"),
             _deep('{"a":', "}", 100_000)),
        Case("JSON top level a list", "error", ("expected an object with a 'frames' list",), json_text(lambda t: b"[]")),
        Case("empty transforms.json", "error", ("malformed JSON",), json_text(lambda t: b"")),
        Case("fl_x NaN literal", "error", ("'fl_x' must be a positive number",),
             json_text(lambda t: t.replace('"fl_x": 20.0', '"fl_x": NaN').encode())),
        Case("fl_x=1e308", "error", ("frame 0", "'fl_x' = 1e+308 is out of range"), _top(fl_x=1e308)),
        Case("fl_x=1e30", "error", ("'fl_x' = 1e+30 is out of range",), _top(fl_x=1e30)),
        Case("fl_y=1e13", "error", ("'fl_y' = 1e+13",), _top(fl_y=1e13)),
        Case("pinhole fl_x=1e9 on 32 px", "error", ("'fl_x' = 1e+09", "ORTHOGRAPHIC"), _top(fl_x=1e9)),
        Case("pinhole fl_x=1e-6", "error", ("'fl_x' = 1e-06", "179.8 degrees"), _top(fl_x=1e-6)),
        Case("cx=1e9", "error", ("'cx' = 1e+09", "principal point"), _top(cx=1e9)),
        Case("cy=-1e6", "error", ("'cy' = -1e+06",), _top(cy=-1e6)),
        Case("fl_x true", "error", ("'fl_x' must be a positive number, got True",), _top(fl_x=True)),
        Case("w=32.5", "error", ("'w' must be a whole number of pixels",), _top(w=32.5)),
        Case("w=1e308", "error", ("'w' must be a whole number of pixels",), _top(w=1e308)),
        Case("camera_angle_x=1e308", "error", ("'camera_angle_x' must be an angle",),
             json_edit(lambda m: (m.pop("fl_x"), m.update(camera_angle_x=1e308)))),
        Case("aabb Infinity", "error", ("'aabb' must hold finite numbers",),
             _top(aabb=[[-1, -1, -1], [1, 1, float("inf")]])),
        Case("aabb NaN", "error", ("'aabb' must hold finite numbers",), _top(aabb=[[float("nan")] * 3, [1, 1, 1]])),
        Case("aabb -Infinity", "error", ("'aabb' must hold finite numbers",),
             _top(aabb=[[float("-inf"), -1, -1], [1, 1, 1]])),
        Case("pixel_size_um Infinity", "error", ("'pixel_size_um' must be a positive finite number", "inf"),
             _top(pixel_size_um=float("inf"))),
        Case("pixel_size_um NaN", "error", ("'pixel_size_um' must be a positive finite number",),
             _top(pixel_size_um=float("nan"))),
        Case("pixel_size_um 0", "error", ("'pixel_size_um'",), _top(pixel_size_um=0)),
        Case("pixel_size_um -1", "error", ("'pixel_size_um'",), _top(pixel_size_um=-1)),
        Case("pixel_size_um a string", "error", ("'pixel_size_um'",), _top(pixel_size_um="1.5")),
        Case("pixel_size_um true", "error", ("'pixel_size_um'",), _top(pixel_size_um=True)),
        Case("specimen_size Infinity", "error", ("'specimen_size' must be a positive finite number",),
             _top(specimen_size=float("inf"))),
        Case("transform_matrix translation 1e308", "error", ("frame 0", "transform_matrix"),
             _frame(transform_matrix=[[1, 0, 0, 1e308], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])),
        Case("frame a string", "error", ("frame 0 has no 'file_path'",), json_edit(lambda m: m["frames"].__setitem__(0, "x"))),
    ]


def _config() -> list[Case]:
    syn = [("n_horizontal=0", "dataset.n_horizontal: must be >= 3"), ("n_vertical=1", "dataset.n_vertical: must be"),
           ("noise=-1", "dataset.noise: must be >= 0"), ("camera=fisheye", "dataset.camera: must be one of pinhole"),
           ("width=5", "dataset.width: must be >= 11"), ("supersample=0", "dataset.supersample: must be >= 1"),
           ("texture=1.5", "dataset.texture: must be < 1"), ("specimen=coral", "dataset.specimen: must be one of"),
           ("seed=abc", "dataset: bad value for key 'seed'")]
    cases = [Case(f"synthetic dataset.{o}", "error", (n,), dataset="synthetic",
                  overrides=[f"{'+' if o.startswith('specimen') else ''}dataset.{o}"]) for o, n in syn]
    cases += [
        Case("synthetic +dataset.n_horizntal=3", "error", ("dataset.n_horizntal: unknown key", "valid keys:",
                                                           "n_horizontal"),
             overrides=["+dataset.n_horizntal=3"], dataset="synthetic"),
        Case("synthetic +dataset.path", "error", ("dataset.path: unknown key for dataset kind 'synthetic'",),
             overrides=["+dataset.path=/tmp"], dataset="synthetic"),
        Case("+dataset.dowscale=4", "error", ("dataset.dowscale: unknown key", "valid keys: kind, path, undistort, source, downscale"),
             overrides=["+dataset.dowscale=4"]),
        Case("+dataset.params on transforms", "error", ("dataset.params: unknown key",), overrides=["+dataset.params=1"]),
        Case("non-ASCII dataset.path unquoted", "error", ("Hydra's override grammar", "dataset.path='"),
             _path("sc\u00e8ne")),
        Case("dataset.path an image file", "error", ("dataset.path:", "view_01.png is an image file"),
             _path("view_01.png")),
        Case("dataset.path a symbolic link loop", "error", ("dataset.path:", "symbolic link that loops"),
             _both(symlink_loop("loop"), _path("loop"))),
        Case("dataset.path the json file itself", "ok", ("check: OK",), _path("transforms.json")),
        Case("dataset.path /dev/null", "error", ("/dev/null", "no transforms.json"),
             lambda r: ["dataset.path=/dev/null"]),
        Case("colorize.references=one beside a folder 'one'", "warning",
             ("unknown preset 'one'", "write ./one"), _folder_named("one", True),
             overrides=["colorize.references=one"], in_case_dir=True),
        Case("colorize.references=./one (a folder)", "ok", ("references './one'",), _folder_named("one", True),
             overrides=["colorize.references=./one", "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0"],
             in_case_dir=True, absent=("stage 2 (stage=color) would stop",)),
        Case("stage=all on 32x24 images with TCM/CCM", "error",
             ("TCM and CCM need stage-2 images of at least 32x32 px", "these are 32x24 px"),
             _folder_named("refs", True), overrides=[*TINY, "colorize.references=./refs"], stage="all",
             in_case_dir=True),
        Case("stage=all on 32x24 images, CCM only", "error", ("CCM needs stage-2 images of at least 32x32 px", "these are 16x12 px"),
             _folder_named("refs", True), overrides=[*TINY, "colorize.references=./refs", "train.downscale=2",
                                                      "colorize.losses.tcm.weight=0"], stage="all", in_case_dir=True),
        Case("stage=check without references", "ok", ("stage=gray", "stage 2 needs references: colorize.references=")),
        Case("stage=check says the real training size", "ok", ("1500 steps at 32x24 px",),
             overrides=["train.width=288"], absent=("288 px wide",)),
        Case("stage=gray: metrics.json strict JSON", "ok", ("stage 1 (gs2d)",), overrides=TINY, stage="gray"),
    ]
    return cases


def _tiff() -> list[Case]:
    from hostile_tiff import tiff_cases

    return tiff_cases()


CASES: list[Case] = [*_images(), *_json(), *_config(), *_tiff()]
