"""Stage-1 training (2DGS + ACT, quick preset) on the synthetic scene's true cameras and on calibrated ones.

Protocol: ``benchmarks/calib_synthetic.py`` calibrates all 40 views of the textured scene (the 8 test views held
out with ``--holdout 'test_*'``: they get cameras from the same adjustment, their pixels never train). The
calibrated dataset lives in its own world frame (a similarity of the true one), so each run is evaluated on
its own held-out cameras; the targets are the same clean test images. Both runs train at half the rendered
size (``dataset.downscale=2``), one thread, the same seed (``--seeds``: several, paired), without the mesh; the calibrated run uses its own sparse
points, masks and box. Printed: held-out and training PSNR/SSIM of both runs and their difference.

    .venv/bin/python benchmarks/calib_training.py [--width 576 --height 384 --texture 0.6]
        [--models orthographic] [--bench /tmp/arcsem_calib_bench] [--out /tmp/arcsem_calib_training] [--seeds 0 1 2]

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
    args, extra = ap.parse_known_args()
    rows = []
    for model in args.models:
        scene = Path(ensure_scene(texture=args.texture, camera=model, width=args.width, height=args.height)).parent
        calibrated = Path(args.bench) / f"{model}_{args.width}" / "dataset"
        if not (calibrated / "transforms.json").is_file():
            raise SystemExit(f"{calibrated}: run benchmarks/calib_synthetic.py --out {args.bench} first")
        for seed in args.seeds:
            for cams, data in (("true", scene), ("calibrated", calibrated)):
                run = Path(args.out) / (f"{model}_{cams}" + (f"_s{seed}" if seed else ""))
                m = held_out(train(data, run, extra, seed))
                rows.append({"model": model, "cameras": cams, "seed": seed,
                             **{f"{s}_{k}": v for s, d in m.items() for k, v in d.items()}})
    print("| model | seed | cameras | held-out PSNR | held-out SSIM | train PSNR | train SSIM |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['seed']} | {r['cameras']} | {r['test_psnr']:.2f} | {r['test_ssim']:.4f} | "
              f"{r['train_psnr']:.2f} | {r['train_ssim']:.4f} |")
    for model in args.models:
        diffs = []
        for seed in args.seeds:
            t, c = (next(r for r in rows if r["model"] == model and r["cameras"] == k and r["seed"] == seed)
                    for k in ("true", "calibrated"))
            diffs.append(c["test_psnr"] - t["test_psnr"])
        print(f"{model}: held-out PSNR calibrated - true = {sum(diffs) / len(diffs):+.2f} dB (mean of seeds "
              f"{args.seeds}: {', '.join(f'{d:+.2f}' for d in diffs)})")
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "calib_training.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
