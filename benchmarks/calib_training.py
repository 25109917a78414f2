"""Stage-1 training (2DGS + ACT, quick preset) on the synthetic scene's true cameras and on calibrated ones.

Protocol: ``benchmarks/calib_synthetic.py`` calibrates all 40 views of the textured scene (the 8 test views held
out with ``--holdout 'test_*'``: they get cameras from the same adjustment, their pixels never train). The
calibrated dataset lives in its own world frame (a similarity of the true one), so each run is evaluated on
its own held-out cameras; the targets are the same clean test images. Both runs train at half the rendered
size (``dataset.downscale=2``), one thread, the same seed (``--seeds``: several, paired), without the mesh; the calibrated
run uses its own masks and box. The Gaussians start from points (``--init``):

* ``scene``: both runs from the scene's 20,000 surface points, carried into the calibrated frame by the similarity
  that maps the true cameras onto the calibrated ones (:func:`frame_similarity`): the runs differ by their cameras
  only;
* ``own``: the calibrated run from the calibration's sparse points (what a user's dataset has), the true run from
  the scene's points: the difference adds the initialisation's.

Printed: held-out and training PSNR/SSIM of every run and the held-out differences.

    .venv/bin/python benchmarks/calib_training.py [--width 576 --height 384 --texture 0.6] [--init scene own]
        [--models orthographic] [--bench /tmp/arcsem_calib_bench] [--out /tmp/arcsem_calib_training] [--seeds 0 1 2]
        [--no-true]   # the calibrated runs only (issue 39's line: own start against the scene's points, same cameras)

Run ``calib_synthetic.py`` with the same ``--width/--height/--texture/--out`` first (its ``--out`` is
``--bench`` here).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

__all__ = ["frame_similarity", "held_out", "scene_points_dataset", "train"]


def frame_similarity(true_dir: Path, cal_dir: Path):
    """``(s, Q, d)`` with ``X_cal = s Q X_true + d`` for two datasets of the same views: ``Q`` the best rotation
    of the cameras (``R_cal Q ~ R_true``, orthogonal Procrustes), then ``s, d`` by least squares on where the
    views put the world: the image position of the world origin (orthographic: ``s`` is the ratio of the pixels
    per unit), or the camera centres (pinhole)."""
    import numpy as np
    from calib_synthetic import best_world_rotation, read_cameras  # benchmarks/, beside this script

    (T, ortho), (C, _) = read_cameras(true_dir / "transforms.json"), read_cameras(cal_dir / "transforms.json")
    names = sorted(set(T) & set(C))
    Q = best_world_rotation(np.stack([T[n][0] for n in names]), np.stack([C[n][0] for n in names]))
    if ortho:  # fl_c (R_c (s Q X + d - c_c))_xy = fl_t (R_t (X - c_t))_xy for all X
        s = float(np.mean([T[n][2] / C[n][2] for n in names]))
        A = np.concatenate([C[n][0][:2] for n in names])
        b = np.concatenate([(C[n][0] @ C[n][1])[:2] - T[n][2] / C[n][2] * (T[n][0] @ T[n][1])[:2] for n in names])
        d = np.linalg.lstsq(A, b, rcond=None)[0]
    else:      # centres: c_c = s Q c_t + d
        A = np.concatenate([np.concatenate([(Q @ T[n][1])[:, None], np.eye(3)], 1) for n in names])
        x = np.linalg.lstsq(A, np.concatenate([C[n][1] for n in names]), rcond=None)[0]
        s, d = float(x[0]), x[1:]
    return s, Q, d


def scene_points_dataset(scene: Path, calibrated: Path, out: Path) -> Path:
    """``out``: the calibrated dataset (links) with the scene's points carried into its frame."""
    from arcsem.ply import read_points, write_points

    s, Q, d = frame_similarity(scene, calibrated)
    X, colors = read_points(scene / "points3d.ply")
    out.mkdir(parents=True, exist_ok=True)
    for p in calibrated.iterdir():
        if p.name != "points3d.ply" and not (out / p.name).exists():
            (out / p.name).symlink_to(p.resolve())
    write_points(out / "points3d.ply", (s * X @ Q.T + d).astype("float32"), colors)
    return out


def train(dataset: Path, run_dir: Path, extra: list[str], seed: int = 0) -> dict:
    """Run ``arcsem`` stage 1 on ``dataset`` into ``run_dir`` (reused when its metrics are complete)."""
    metrics = run_dir / "metrics.json"
    if metrics.is_file() and json.loads(metrics.read_text()).get("status") == "complete":
        return json.loads(metrics.read_text())
    exe = Path(sys.executable).with_name("arcsem")
    cmd = [str(exe), "dataset=transforms", f"dataset.path={dataset}", "dataset.downscale=2", "backbone=gs2d",
           "act=paper", "stage=gray", "threads=1", f"seed={seed}", "mesh.enabled=false", f"hydra.run.dir={run_dir}", *extra]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env={**os.environ, "TQDM_DISABLE": "1"})
    return json.loads(metrics.read_text())


def held_out(metrics: dict) -> dict:
    """``{split: {psnr, ssim}}`` of a run's stage-1 evaluation."""
    ev = metrics["stages"]["gray"]["stage1"]
    return {s: {k: ev[s].get(k) for k in ("psnr", "ssim")} for s in ("test", "train")}


def main() -> None:
    from arcsem.synthetic import ensure_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=576)
    ap.add_argument("--height", type=int, default=384)
    ap.add_argument("--texture", type=float, default=0.6)
    ap.add_argument("--models", nargs="+", default=["orthographic"])
    ap.add_argument("--bench", default="/tmp/arcsem_calib_bench", help="--out of calib_synthetic.py")
    ap.add_argument("--out", default="/tmp/arcsem_calib_training")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="training seeds (paired: one run per camera set)")
    ap.add_argument("--init", nargs="+", default=["scene", "own"], choices=["scene", "own"],
                    help="the calibrated runs' initial points (module docstring)")
    ap.add_argument("--no-true", action="store_true",
                    help="skip the true-camera runs: compare the calibrated starts with each other (needs --init scene own)")
    args, extra = ap.parse_known_args()
    rows = []
    for model in args.models:
        scene = Path(ensure_scene(texture=args.texture, camera=model, width=args.width, height=args.height)).parent
        calibrated = Path(args.bench) / f"{model}_{args.width}" / "dataset"
        if not (calibrated / "transforms.json").is_file():
            raise SystemExit(f"{calibrated}: run benchmarks/calib_synthetic.py --out {args.bench} first")
        runs = [] if args.no_true else [("true", "scene", scene)]
        if "scene" in args.init:
            runs.append(("calibrated", "scene", scene_points_dataset(scene, calibrated,
                                                                     Path(args.out) / f"{model}_scene_points")))
        if "own" in args.init:
            runs.append(("calibrated", "own", calibrated))
        for seed in args.seeds:
            for cams, init, data in runs:
                tag = f"{model}_{cams}" + ("_scene_init" if cams == "calibrated" and init == "scene" else "")
                run = Path(args.out) / (tag + (f"_s{seed}" if seed else ""))
                m = held_out(train(data, run, extra, seed))
                rows.append({"model": model, "cameras": cams, "init": init, "seed": seed,
                             **{f"{s}_{k}": v for s, d in m.items() for k, v in d.items()}})
    print("| model | seed | cameras | initial points | held-out PSNR | held-out SSIM | train PSNR | train SSIM |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['seed']} | {r['cameras']} | {r['init']} | {r['test_psnr']:.2f} | "
              f"{r['test_ssim']:.4f} | {r['train_psnr']:.2f} | {r['train_ssim']:.4f} |")
    pick = lambda model, seed, cams, init: next(r for r in rows if (r["model"], r["seed"], r["cameras"], r["init"])
                                                == (model, seed, cams, init))
    for model in args.models:
        for init in [] if args.no_true else args.init:
            diffs = [pick(model, s, "calibrated", init)["test_psnr"] - pick(model, s, "true", "scene")["test_psnr"]
                     for s in args.seeds]
            print(f"{model}, calibrated run from {init} points: held-out PSNR calibrated - true = "
                  f"{sum(diffs) / len(diffs):+.2f} dB (seeds {args.seeds}: {', '.join(f'{d:+.2f}' for d in diffs)})")
        if set(args.init) == {"scene", "own"}:  # issue 39's line: the calibration's start against the scene's points
            diffs = [pick(model, s, "calibrated", "own")["test_psnr"] - pick(model, s, "calibrated", "scene")["test_psnr"]
                     for s in args.seeds]
            print(f"{model}, calibrated cameras, own start - scene's points = {sum(diffs) / len(diffs):+.2f} dB "
                  f"(seeds {args.seeds}: {', '.join(f'{d:+.2f}' for d in diffs)})")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "calib_training.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
