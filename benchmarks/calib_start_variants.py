"""Issue 39's training line, by the calibration's initial points and box: stage 1 (2DGS + ACT, quick, as
``calib_training.py``) on one calibrated dataset of the built-in scene, started four ways.

* ``dense``: the calibration as written (sparse points + the dense start, ``aabb`` the specimen's box);
* ``keypoints``: the dense start without its surface fill (the ply cut after the keypoint points);
* ``grown``: as ``dense`` with ``aabb`` replaced by ``content_aabb`` (the box grown to every point, what the
  calibration wrote before the two boxes were split);
* ``sparse``: a second calibration with ``--dense-features 0``.

    .venv/bin/python benchmarks/calib_synthetic.py --models orthographic --out BENCH     # the calibrated dataset
    .venv/bin/python benchmarks/calib_start_variants.py --bench BENCH --out OUT [--seeds 0 1 2]

Prints held-out PSNR per variant and seed (the true cameras' run from the scene's points: calib_training.py).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def variant(calibrated: Path, out: Path, name: str) -> Path:
    """The dataset of variant ``name`` (links to ``calibrated``; ``sparse`` is calibrated anew by the caller)."""
    from arcsem.ply import read_points, write_points

    out.mkdir(parents=True, exist_ok=True)
    meta = json.loads((calibrated / "transforms.json").read_text())
    for p in calibrated.iterdir():
        if p.name not in ("points3d.ply", "transforms.json") and not (out / p.name).exists():
            (out / p.name).symlink_to(p.resolve())
    X, colors = read_points(calibrated / "points3d.ply")
    if name == "keypoints":
        rep = json.loads((calibrated / "report" / "calibration.json").read_text())
        keep = rep["tracks"] + rep["dense"]["keypoint_points"]
        X, colors = X[:keep], colors[:keep]
    if name == "grown":
        meta["aabb"] = meta["content_aabb"]
    write_points(out / "points3d.ply", X, colors)
    (out / "transforms.json").write_text(json.dumps(meta))
    return out


def main() -> None:
    from calib_training import held_out, train

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bench", required=True, help="--out of calib_synthetic.py")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--variants", nargs="+", default=["dense", "keypoints", "grown", "sparse"])
    args, extra = ap.parse_known_args()
    calibrated = Path(args.bench) / "orthographic_576" / "dataset"
    out = Path(args.out)
    for name in args.variants:
        if name == "sparse":
            data = out / "sparse"
            if not (data / "transforms.json").is_file():
                from arcsem.cli.calibrate import main as calibrate

                src = Path(args.bench) / "orthographic_576"
                cmd = json.loads((calibrated / "report" / "calibration.json").read_text())["options"]
                px = json.loads((calibrated / "transforms.json").read_text())["pixel_size_um"]
                code = calibrate([str(src / "input"), "--out", str(data), "--tilts", str(src / "tilts.csv"),
                                  "--holdout", "test_*", "--pixel-size", str(px), "--dense-features", "0"])
                if code:
                    raise SystemExit(f"calibration failed ({code}); options of the first: {cmd}")
        elif name == "dense":
            data = calibrated
        else:
            data = variant(calibrated, out / name, name)
        for seed in args.seeds:
            m = held_out(train(data, out / f"train_{name}_s{seed}", extra, seed))
            print(f"| {name} | {seed} | {m['test']['psnr']:.2f} | {m['test']['ssim']:.4f} | {m['train']['psnr']:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
