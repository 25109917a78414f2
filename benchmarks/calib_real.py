"""Calibration of real SEM tilt series (issue 18, "real SEM"): RMS reprojection error per series.

The series are not in the repository. The ones measured (benchmarks/results/calibration.md) are the two
3-view examples of Töberg & Reithmeier's 3D-SEM code (BSD-3-Clause, https://github.com/Karido/3D-SEM):
``res/dsa`` (2000 x 2000 px, DSA_01..03.png) and ``res/quarz`` (1200 x 1200 px, Quarz_01..03.png), PNG files
without metadata, tilted by a few degrees about one axis: they are calibrated by affine factorisation
(``--init factorization``), one world unit = one pixel.

    git clone https://github.com/Karido/3D-SEM /tmp/3D-SEM
    .venv/bin/python benchmarks/calib_real.py /tmp/3D-SEM/res/dsa /tmp/3D-SEM/res/quarz [--out DIR]

Extra flags go to arcsem-calibrate (e.g. ``--tilts`` for series with known angles).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    from arcsem.cli.calibrate import main as calibrate_main

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--out", default="/tmp/arcsem_calib_real")
    args, extra = ap.parse_known_args()
    if not any(a.startswith(("--tilts", "--init")) for a in extra):
        extra = ["--init", "factorization", *extra]
    rows = []
    for folder in map(Path, args.folders):
        out = Path(args.out) / folder.name
        t0 = time.perf_counter()
        code = calibrate_main([str(folder), "--out", str(out), "--overwrite", *extra])
        if code:
            raise SystemExit(f"{folder}: calibration failed ({code})")
        r = json.loads((out / "report" / "calibration.json").read_text())
        axis = r["tilt_axes"][0] if r["tilt_axes"] else {}
        rows.append({"series": folder.name, "views": len(r["per_view"]), "rms_px": r["rms_px"],
                     "median_px": r["median_px"], "tracks": r["tracks"], "observations": r["observations"],
                     "step_deg": axis.get("mean_step_deg", float("nan")),
                     "axis_in_image_deg": axis.get("image_angle_deg", float("nan")),
                     "per_view_rms": [round(v["rms_px"], 3) for v in r["per_view"]],
                     "seconds": time.perf_counter() - t0})
    print("| series | views | RMS px | median px | tracks | observations | tilt step (deg) | axis in image (deg) | per-view RMS | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['series']} | {r['views']} | {r['rms_px']:.3f} | {r['median_px']:.3f} | {r['tracks']} | "
              f"{r['observations']} | {r['step_deg']:.2f} | {r['axis_in_image_deg']:.1f} | {r['per_view_rms']} | "
              f"{r['seconds']:.1f} |")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "calib_real.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
