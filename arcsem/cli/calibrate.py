"""``arcsem-calibrate``: orthographic cameras for a folder of SEM images, written as an arcsem dataset.

Examples::

    arcsem-calibrate --inspect raw/                  # what the files say: tilt, rotation, pixel size, crop
    arcsem-calibrate raw/ --out pollen/              # calibrate; pollen/transforms.json + images, masks, ...
    arcsem-calibrate raw/ --out pollen/ --tilts -9,-6,-3,0,3,6,9     # files without stage metadata
    arcsem-calibrate raw/ --out pollen/ --tilts tilts.csv --holdout 'test_*'

Method, formats and outputs: docs/calibration.md. Bad input ends with one ``error:`` line and exit code 2;
the input folder is never written.
"""
from __future__ import annotations

import argparse
import re
import shlex
import shutil
import sys
import tempfile
from pathlib import Path

__all__ = ["build_parser", "main"]

OUTPUTS = ("transforms.json", "points3d.ply", "images", "masks", "sparse", "report")


def build_parser() -> argparse.ArgumentParser:
    from ..calib.pipeline import CalibrationOptions as O

    ap = argparse.ArgumentParser(prog="arcsem-calibrate", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="folder of SEM images (.tif .png .jpg ...) of one specimen")
    ap.add_argument("--inspect", action="store_true", help="print what the files say (a table) and stop")
    ap.add_argument("--out", help="dataset folder to write (must not lie inside the input folder)")
    ap.add_argument("--overwrite", action="store_true", help="replace a dataset already in --out")
    ap.add_argument("--tilts", help="stage tilts in degrees: a comma list in file order, or a CSV 'file,tilt[,rotation]'")
    ap.add_argument("--pixel-size", type=float, help="pixel size in micrometres (overrides the metadata)")
    ap.add_argument("--crop-bottom", type=int, help="rows of the data bar to cut (overrides its detection)")
    ap.add_argument("--holdout", help="glob of image file names to hold out of training (split=test), e.g. 'test_*'")
    ap.add_argument("--init", choices=("auto", "stage", "factorization"), default=O.init,
                    help="initial cameras: stage angles (auto: the metadata or --tilts) or affine factorisation")
    ap.add_argument("--per-view-scale", action="store_true", help="one magnification per view (drift)")
    ap.add_argument("--camera", choices=("orthographic", "perspective"), default=O.camera,
                    help="orthographic (parallel beam: high magnification) or perspective (a far pinhole refined "
                    "from it: low magnification, where the scan's pivot is not far against the field of view)")
    ap.add_argument("--focal-px", type=float, help="perspective: hold this focal length in pixels (default: "
                    "estimate it, starting from the paper's 50,000 px at 3072 px width)")
    ap.add_argument("--angle-sigma", type=float, default=O.angle_sigma,
                    help="degrees: how far the stage angles are trusted (prior of their per-view corrections)")
    ap.add_argument("--flip-depth", action="store_true", help="take the mirrored relief (a microscope that tilts "
                    "the other way; a factorised series with the substrate on the wrong side)")
    ap.add_argument("--features", type=int, default=O.max_features, help="SIFT keypoints per image")
    ap.add_argument("--dense-features", type=int, default=O.dense_features, help="keypoints per image of the dense "
                    "start: points triangulated with the calibrated cameras for training to start from (0: the "
                    "adjustment's sparse points only)")
    ap.add_argument("--feature-scale", type=float, help="compute features on a copy scaled by this (default: "
                    "longest side 1600 px)")
    ap.add_argument("--masks", help="folder of specimen masks (same file stems as the images) to use instead of "
                    "the automatic ones")
    ap.add_argument("--no-masks", action="store_true", help="write no masks")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    return ap


def _check_paths(args) -> tuple[Path, Path | None]:
    from ..errors import ConfigError, DataError
    from ..guard import inside

    folder = Path(args.folder).expanduser().resolve()
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder")
    if args.inspect:
        return folder, None
    if not args.out:
        raise ConfigError("--out DATASET is required (or --inspect)")
    out = Path(args.out).expanduser().resolve()
    if inside(out, folder) or inside(folder, out):
        raise ConfigError(f"--out {out}: the dataset must not be written into the input folder {folder} (nor the "
                          "input into it); choose another folder")
    if (out / "transforms.json").exists() and not args.overwrite:
        raise ConfigError(f"{out} already holds a dataset (transforms.json); use --overwrite to replace it")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file, not a folder")
    return folder, out


def _check_angles(series, args) -> None:
    from ..errors import DataError

    if len(series) < 2:
        raise DataError(f"{series.images[0].path}: a single image; calibration needs two or more views of the specimen")
    if args.init == "factorization":
        return
    lacking = [im for im, t in zip(series.images, series.tilts) if t is None]
    if lacking:
        src = lacking[0].meta.source
        why = f"{src} gives none readable" if src and src != "no vendor metadata found" else "no vendor metadata found"
        raise DataError(f"{lacking[0].path}: no stage tilt ({why}); give --tilts (a list or a CSV) "
                        "or --init factorization")


def _check_camera(args) -> None:
    import math

    from ..errors import ConfigError

    for flag, value, least in (("--features", args.features, 16), ("--dense-features", args.dense_features, 0)):
        if value < least:
            raise ConfigError(f"{flag} {value}: must be at least {least} keypoints per image")
    if args.focal_px is None:
        return
    if args.camera != "perspective":
        raise ConfigError(f"--focal-px {args.focal_px:g}: a focal length is for --camera perspective only")
    if not math.isfinite(args.focal_px) or args.focal_px <= 0:
        raise ConfigError(f"--focal-px {args.focal_px:g}: must be a positive number of pixels")


def _user_masks(folder: Path, series):
    import numpy as np

    from ..data.io import IMAGE_EXTS, read_mask
    from ..errors import DataError

    masks = []
    for im in series.images:
        cand = [folder / f"{im.path.stem}{e}" for e in IMAGE_EXTS]
        path = next((c for c in cand if c.is_file()), None)
        if path is None:
            raise DataError(f"{folder}: no mask for {im.path.name} (expected {im.path.stem}.png or another image type)")
        m = read_mask(path)
        if (m.shape[1], m.shape[0]) != im.size:
            raise DataError(f"{path}: mask is {m.shape[1]}x{m.shape[0]} but {im.path.name} is {im.size[0]}x{im.size[1]}")
        masks.append(np.ascontiguousarray(series.crop.apply(m)))
    return masks


def _write(out: Path, series, cal, args, opts) -> None:
    import numpy as np

    from ..calib.frame import specimen_points
    from ..calib.report import write_report
    from ..calib.write import write_dataset
    from ..guard import allowed_roots, protect

    out.mkdir(parents=True, exist_ok=True)
    if args.overwrite:
        for name in OUTPUTS:
            p = out / name
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    (lo, hi), (clo, chi) = _boxes(cal, specimen_points(cal.frame.substrate, cal.frame.height, cal.X))
    pad, cpad = 0.1 * (hi - lo), 0.1 * (chi - clo)
    extra = {"world_unit": cal.unit, "content_aabb": np.stack([clo - cpad, chi + cpad]).tolist(),
             "frames": [{"stage_tilt_deg": t, "stage_rotation_deg": r, "stage_angles_from": ts, "pixel_size_from": ps,
                         "intensity_levels": im.levels.describe() if im.levels else None}
                        for t, r, ts, ps, im in zip(series.tilts, series.rotations, series.sources["tilt"],
                                                    series.sources["pixel"], series.images)],
             "calibration": {"tool": "arcsem-calibrate", "rms_px": cal.stats["rms_px"], "report": "report/report.md",
                             "crop": vars(series.crop) | {"reasons": list(series.crop.reasons)}}}
    p_um = series.pixel_size_m * 1e6 if series.pixel_size_m else None
    command = "arcsem-calibrate " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    with protect(allowed_roots(out) + [Path(tempfile.gettempdir())], input_dirs=[series.folder], own=[out]):
        write_dataset(out, series.names, [series.pixels(i) for i in range(len(series))], cal.masks, cal.views,
                      cal.X, cal.colors, cal.obs, size=series.size, splits=cal.splits, dense=(cal.dense, cal.dense_colors),
                      pixel_size_um=p_um, aabb=np.stack([lo - pad, hi + pad]), extra=extra)
        write_report(out, series, cal, {k: v for k, v in vars(opts).items()}, command)


def _boxes(cal, specimen):
    """The dataset's two boxes before padding, each ``(lo, hi)`` ``[3]``: the specimen's (its points' 1-99
    percentiles: ``aabb``, the Gaussians' length scale) and the content's (grown to the 0.5-99.5 percentiles of every
    point, sparse and dense: the substrate and debris each view shows; ``content_aabb``, the Plenoxels grid). Growing
    ``aabb`` itself would scale the Gaussians' learning rate and split threshold with the substrate's size, not the
    specimen's (one seed each on the built-in scene: 25.51 dB held out with the grown box and the dense start, 26.12
    with the specimen's; benchmarks/results/calibration.md section 9)."""
    import numpy as np

    spec = cal.X[specimen]
    lo, hi = np.percentile(spec, 1, axis=0), np.percentile(spec, 99, axis=0)
    everything = cal.X if cal.dense is None or not len(cal.dense) else np.concatenate([cal.X, cal.dense])
    return (lo, hi), (np.minimum(lo, np.percentile(everything, 0.5, axis=0)),
                      np.maximum(hi, np.percentile(everything, 99.5, axis=0)))


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--tilts -15,-9,0`` as written: argparse takes a value that starts with '-' for an option unless it is one
    number, so a list of numbers is joined to its option (``--tilts=-15,-9,0``)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--tilts" and i + 1 < len(argv) and re.fullmatch(r"-[\d.,eE+\s-]*", argv[i + 1]):
            out.append(f"--tilts={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(_join_negative_values(list(sys.argv[1:] if argv is None else argv)))
    from .errors import call_reporting_errors

    def run() -> int:
        from ..calib.pipeline import CalibrationOptions, calibrate
        from ..sem.series import inspect_table, read_series

        folder, out = _check_paths(args)
        series = read_series(folder, args.tilts, args.pixel_size, args.crop_bottom, strict=not args.inspect)
        if args.inspect:
            print(inspect_table(series))
            return 0
        _check_angles(series, args)
        _check_camera(args)
        opts = CalibrationOptions(max_features=args.features, dense_features=args.dense_features, angle_sigma=args.angle_sigma, feature_scale=args.feature_scale, init=args.init,
                                  per_view_scale=args.per_view_scale, holdout=args.holdout,
                                  camera=args.camera, focal_px=args.focal_px, flip_depth=args.flip_depth,
                                  masks=not args.no_masks and not args.masks)
        user_masks = _user_masks(Path(args.masks).expanduser().resolve(), series) if args.masks else None
        cal = calibrate(series, opts)
        if user_masks is not None:
            cal.masks = user_masks
        _write(out, series, cal, args, opts)
        s = cal.stats
        print(f"{out / 'transforms.json'}: {len(series)} views, RMS {s['rms_px']:.3f} px, {s['tracks']} points "
              f"(one world unit = one {cal.unit}; report: {out / 'report' / 'report.md'})")
        return 0

    return call_reporting_errors(run, args.debug)


if __name__ == "__main__":
    sys.exit(main())
