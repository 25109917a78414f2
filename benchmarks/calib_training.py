"""Stage-1 training (2DGS + ACT, quick preset) on the synthetic scene's true cameras and on calibrated ones.

Protocol: ``benchmarks/calib_synthetic.py`` calibrates all 40 views of the textured scene (the 8 test views held
out with ``--holdout 'test_*'``: they get cameras from the same adjustment, their pixels never train). The
calibrated dataset lives in its own world frame (a similarity of the true one), so each run is evaluated on
its own held-out cameras; the targets are the same clean test images. Both runs train at half the rendered
size (``dataset.downscale=2``), one thread, seed 0, without the mesh; the calibrated run uses its own sparse
points, masks and box. Printed: held-out and training PSNR/SSIM of both runs and their difference.

    .venv/bin/python benchmarks/calib_training.py [--width 576 --height 384 --texture 0.6]
        [--models orthographic] [--bench /tmp/arcsem_calib_bench] [--out /tmp/arcsem_calib_training]

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

__all__ = ["held_out", "train"]


def train(dataset: Path, run_dir: Path, extra: list[str]) -> dict:
    """Run ``arcsem`` stage 1 on ``dataset`` into ``run_dir`` (reused when its metrics are complete)."""
    metrics = run_dir / "metrics.json"
    if metrics.is_file() and json.loads(metrics.read_text()).get("status") == "complete":
        return json.loads(metrics.read_text())
    exe = Path(sys.executable).with_name("arcsem")
    cmd = [str(exe), "dataset=transforms", f"dataset.path={dataset}", "dataset.downscale=2", "backbone=gs2d",
           "act=paper", "stage=gray", "threads=1", "seed=0", "mesh.enabled=false", f"hydra.run.dir={run_dir}", *extra]
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
    args, extra = ap.parse_known_args()
    rows = []
    for model in args.models:
        scene = Path(ensure_scene(texture=args.texture, camera=model, width=args.width, height=args.height)).parent
        calibrated = Path(args.bench) / f"{model}_{args.width}" / "dataset"
        if not (calibrated / "transforms.json").is_file():
            raise SystemExit(f"{calibrated}: run benchmarks/calib_synthetic.py --out {args.bench} first")
        for cams, data in (("true", scene), ("calibrated", calibrated)):
            m = held_out(train(data, Path(args.out) / f"{model}_{cams}", extra))
            rows.append({"model": model, "cameras": cams, **{f"{s}_{k}": v for s, d in m.items() for k, v in d.items()}})
    print("| model | cameras | held-out PSNR | held-out SSIM | train PSNR | train SSIM |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['cameras']} | {r['test_psnr']:.2f} | {r['test_ssim']:.4f} | {r['train_psnr']:.2f} | "
              f"{r['train_ssim']:.4f} |")
    for model in args.models:
        t, c = (next(r for r in rows if r["model"] == model and r["cameras"] == k) for k in ("true", "calibrated"))
        print(f"{model}: held-out PSNR calibrated - true = {c['test_psnr'] - t['test_psnr']:+.2f} dB")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "calib_training.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
