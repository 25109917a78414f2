"""Calibration of the built-in synthetic scene against its true cameras (issue 18, "synthetic, known cameras").

For each camera model (orthographic, far pinhole) the textured scene is rendered (cached), its ``images/``
(train views with scan noise and exposure drift, test views clean) are copied into an input folder, and a
tilts CSV is written from the true view angles in arcsem's stage convention (``tilt = elevation - 90``,
``rotation = -azimuth``: the two arcs are a stage rotation at 80 degrees of tilt and a tilt series), with
Gaussian noise of ``--angle-noise`` degrees as a microscope's readout would have. ``arcsem-calibrate``
then calibrates all 40 views together (test views held out with ``--holdout 'test_*'``), with the true pixel
size (so that the world unit equals the scene's). Printed per model: the rotation error of every view
after the best world rotation (the calibrated frame differs from the true one by a similarity), the RMS
reprojection error, the automatic masks' intersection over union with the true ones, and the times. Parallel
projection cannot tell a relief from its mirror image (each camera ``R -> diag(-1, -1, 1) R``, points
``X -> -X``); ``mirror_max_rot_deg`` is the error after that reversal, and ``depth_reversed`` says that it fits
better: the cameras are right up to the depth direction, which :mod:`arcsem.calib.frame` chose wrongly
(a failure: the relief is inverted).

    .venv/bin/python benchmarks/calib_synthetic.py [--width 576 --height 384] [--angle-noise 1.0]
        [--texture 0.6] [--models orthographic pinhole] [--out DIR] [--camera perspective ...]

Flags it does not know go to ``arcsem-calibrate`` (``--camera perspective``: pinhole cameras, whose estimated
focal length is printed beside the truth's, 50,000 px at 3072 px width scaled to ``--width``).

The stage-1 training comparison on these datasets is ``benchmarks/calib_training.py``.
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import time
from pathlib import Path

import numpy as np

__all__ = ["best_world_rotation", "prepare_input", "read_cameras", "rotation_errors", "true_rotations"]


def prepare_input(scene: Path, folder: Path, csv: Path, noise_deg: float, seed: int = 0) -> None:
    """Copy the scene's observed images into ``folder`` and write the (noisy) stage angles to ``csv``."""
    meta = json.loads((scene / "transforms.json").read_text())
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    rows = ["file,tilt,rotation"]
    for f in meta["frames"]:
        name = Path(f["file_path"]).name
        shutil.copy(scene / f["file_path"], folder / name)
        tilt, rot = f["elevation"] - 90.0 + rng.normal(0, noise_deg), -f["azimuth"] + rng.normal(0, noise_deg)
        rows.append(f"{name},{tilt:.4f},{rot:.4f}")
    csv.write_text("\n".join(rows) + "\n")


def read_cameras(path: Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray, float]], bool]:
    """``{view: (world->camera rotation [3, 3] (OpenCV axes), centre [3], pixels per unit)}`` of a transforms.json
    and whether its cameras are orthographic."""
    meta = json.loads(path.read_text())
    out = {}
    for f in meta["frames"]:
        c2w = np.array(f["transform_matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0])
        out[Path(f["file_path"]).stem] = (c2w[:3, :3].T, c2w[:3, 3], float(f.get("fl_x", meta.get("fl_x"))))
    return out, meta.get("camera_model") == "ORTHOGRAPHIC"


def true_rotations(path: Path) -> dict[str, np.ndarray]:
    """``{view: world->camera rotation [3, 3]}`` (OpenCV axes) of a transforms.json."""
    return {name: cam[0] for name, cam in read_cameras(path)[0].items()}


def best_world_rotation(Rt: np.ndarray, Rc: np.ndarray) -> np.ndarray:
    """``Q [3, 3]`` with ``Rc[i] Q ~ Rt[i]`` for rotations ``[n, 3, 3]`` (orthogonal Procrustes, no reflection)."""
    U, _, Vt = np.linalg.svd(np.einsum("nji,njk->ik", Rc, Rt))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def rotation_errors(truth: dict[str, np.ndarray], calib: dict[str, np.ndarray], mirror: bool = False
                    ) -> dict[str, float]:
    """Angle (degrees) between calibrated and true rotations after the best common world rotation ``Q``
    (``R_cal Q ~ R_true``, orthogonal Procrustes; no reflection allowed). ``mirror``: compare the depth
    reversal of the calibrated views (``diag(-1, -1, 1) R_cal``) instead."""
    names = sorted(set(truth) & set(calib))
    D = np.diag([-1.0, -1.0, 1.0]) if mirror else np.eye(3)
    Rt, Rc = np.stack([truth[n] for n in names]), np.stack([D @ calib[n] for n in names])
    Q = best_world_rotation(Rt, Rc)
    E = np.einsum("nij,jk,nlk->nil", Rc, Q, Rt)
    ang = np.degrees(np.arccos(np.clip((np.trace(E, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return dict(zip(names, ang.tolist()))


def stage_angle_errors(truth: dict[str, np.ndarray], csv: Path) -> dict[str, float]:
    """Rotation errors of the cameras the given (noisy) stage angles alone describe (arcsem's stage model, the
    true tilt-axis direction): what the calibration starts from."""
    from arcsem.calib.geometry import stage_rotation

    rows = [line.split(",") for line in csv.read_text().splitlines()[1:] if line]
    return rotation_errors(truth, {Path(f).stem: stage_rotation(float(t), float(r)) for f, t, r in rows})


def mask_iou(scene: Path, dataset: Path) -> list[float]:
    """Intersection over union of the automatic masks with the scene's true specimen masks, per view."""
    import cv2

    out = []
    for f in sorted((dataset / "masks").glob("*.png")):
        a, b = cv2.imread(str(f), 0) > 127, cv2.imread(str(scene / "masks" / f.name), 0) > 127
        out.append(float((a & b).sum() / max((a | b).sum(), 1)))
    return out


def run_model(args, model: str) -> dict:
    from arcsem.cli.calibrate import main as calibrate_main
    from arcsem.synthetic import SceneParams, ensure_scene

    params = {"texture": args.texture, "camera": model, "width": args.width, "height": args.height}
    scene = Path(ensure_scene(**params)).parent
    work = Path(args.out) / f"{model}_{args.width}"
    prepare_input(scene, work / "input", work / "tilts.csv", args.angle_noise)
    out = work / "dataset"
    focal = 50_000.0 * args.width / 3072
    p = SceneParams(**params)
    px_per_unit = 0.9 * min(p.width, p.height) / 2.5  # arcsem.synthetic.cameras.arc_cameras
    t0 = time.perf_counter()
    code = calibrate_main([str(work / "input"), "--out", str(out), "--tilts", str(work / "tilts.csv"), "--holdout",
                           "test_*", "--pixel-size", str(1.0 / px_per_unit), "--overwrite", *args.calibrate])
    seconds = time.perf_counter() - t0
    if code:
        raise SystemExit(f"calibration of {model} failed ({code})")
    truth = true_rotations(scene / "transforms.json")
    calib = true_rotations(out / "transforms.json")
    err, err_m = rotation_errors(truth, calib), rotation_errors(truth, calib, mirror=True)
    given = list(stage_angle_errors(truth, work / "tilts.csv").values())
    report = json.loads((out / "report" / "calibration.json").read_text())
    iou = mask_iou(scene, out)
    return {"mask_iou_mean": float(np.mean(iou)), "mask_iou_min": float(np.min(iou)), "angle_noise": args.angle_noise,
            "given_max_rot_deg": max(given), "given_mean_rot_deg": float(np.mean(given)), "model": model, "size": f"{args.width}x{args.height}", "views": len(err), "max_rot_deg": max(err.values()),
            "mean_rot_deg": float(np.mean(list(err.values()))),
            "mirror_max_rot_deg": max(err_m.values()), "depth_reversed": max(err_m.values()) < max(err.values()),
            "rms_px": report["rms_px"],
            "median_px": report["median_px"], "observations": report["observations"], "seconds": seconds,
            "pinhole_focal_px": focal if model == "pinhole" else math.nan, "dataset": str(out),
            "camera": "perspective" if "perspective" in report["bundle"] else "orthographic",
            "focal_px": report["bundle"].get("perspective", {}).get("focal_px", math.nan)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=576)
    ap.add_argument("--height", type=int, default=384)
    ap.add_argument("--texture", type=float, default=0.6)
    ap.add_argument("--angle-noise", type=float, default=1.0, help="degrees of noise on the given stage angles")
    ap.add_argument("--models", nargs="+", default=["orthographic", "pinhole"])
    ap.add_argument("--out", default="/tmp/arcsem_calib_bench")
    args, args.calibrate = ap.parse_known_args()  # other flags go to arcsem-calibrate (--angle-sigma 1 ...)
    rows = [run_model(args, m) for m in args.models]
    cols = ["model", "camera", "focal_px", "size", "views", "angle_noise", "given_max_rot_deg", "given_mean_rot_deg", "max_rot_deg",
            "mean_rot_deg", "mirror_max_rot_deg", "depth_reversed", "rms_px", "median_px", "observations", "mask_iou_mean", "mask_iou_min", "seconds"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.3f}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "calib_synthetic.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
