"""What would an ACT that knew the drift win? Stage 1 with ACT fixed to the scene's true exposures.

Every training view's transform is set to its true ``(contrast, brightness)``
(:func:`arcsem.synthetic.write.true_exposures`) and never trained (``act.lr`` is forced to 0), so the
scene is fitted to drift-corrected images. Compare its held-out PSNR with 2DGS without ACT (the study)
and with the scene without drift (``+dataset.drift=0.0``). Any other overrides are Hydra overrides of
a stage-1 run, e.g. (the quick preset's 2DGS + ACT row)::

    ARCSEM_CACHE=/tmp/c .venv/bin/python benchmarks/act_oracle.py --out multirun/act_oracle/0 \\
        +preset=quick +variant=gs2d_act seed=0 threads=1 train.eval.video=false
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from arcsem.app import set_threads
from arcsem.data import load_scene
from arcsem.synthetic.write import SceneParams, true_exposures
from arcsem.train import stage1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="run directory (metrics.json, stage1/)")
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args(argv)
    with initialize_config_module("arcsem.conf", version_base=None):
        cfg = compose("config", overrides=[*args.overrides, "act.lr=0.0"])
    set_threads(cfg.get("threads"))
    torch.manual_seed(int(cfg.seed))
    scene = load_scene(cfg.dataset)
    meta = json.loads((Path(scene.root) / "transforms.json").read_text())
    truth = true_exposures(SceneParams.from_transforms(meta))
    build = stage1.build_model

    def oracle_build(*a, **k):
        backbone, act = build(*a, **k)
        if act is None:
            raise SystemExit("act_oracle needs ACT on (e.g. variant=gs2d_act)")
        with torch.no_grad():
            for i, name in enumerate(scene.train.names):
                act.weight[i] = truth[name][0]
                act.bias[i] = truth[name][1]
        return backbone, act

    stage1.build_model = oracle_build
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    res = stage1.run_stage1(cfg, scene, args.out / "stage1")
    (args.out / "metrics.json").write_text(json.dumps({"dataset": {"root": str(scene.root)}, "stages": {"gray": res}},
                                                      default=float, indent=1))
    t = res["stage1"]["test"]
    print(f"held-out PSNR {t['psnr']:.2f} dB, SSIM {t['ssim']:.3f}, depth {res['stage1']['depth']['test_mae_pct']:.2f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
