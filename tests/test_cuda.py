"""A GPU where one exists: the PyTorch tile rasterisers on CUDA equal the CPU path, and ``device=cuda`` runs
stage 1 and stage 2 end to end for every backbone. Skipped where torch sees no CUDA device (the project never
depends on one); run with ``pytest -m cuda`` on a GPU machine."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from conftest import write_transforms_scene
from test_config import compose_with
from test_fused import _scene, render

pytestmark = [pytest.mark.cuda,
              pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available())")]

OUTS = ("rgb", "alpha", "depth")


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_torch_rasterizer_on_cuda_matches_cpu(kind, model):
    """Values and gradients (every splat parameter) of the PyTorch path, float64, CUDA against CPU."""
    params, cams = _scene(kind, model, seed=3)
    res = {}
    for dev in ("cpu", "cuda"):
        p = [t.detach().to(dev).requires_grad_() for t in params]
        out = render(kind, p, cams.to(device=dev), impl="torch")
        g = torch.Generator().manual_seed(1)
        loss = sum((out[k] * torch.rand(out[k].shape, generator=g, dtype=out[k].dtype).to(dev)).sum() for k in OUTS)
        grads = torch.autograd.grad(loss, p)
        res[dev] = [out[k].detach().cpu() for k in OUTS], [x.cpu() for x in grads]
    for name, a, b in zip(OUTS + ("means", "quats", "scales", "opacities", "colors"),
                          res["cuda"][0] + res["cuda"][1], res["cpu"][0] + res["cpu"][1]):
        err = ((a - b).abs().max() / b.abs().max().clamp_min(1e-12)).item()
        assert err < 1e-9, f"{name}: relative error {err:.2e} between CUDA and CPU"


@pytest.mark.parametrize("backbone,stages,extra", [
    ("gs2d", ["gray", "color"], []), ("gs3d", ["gray", "color"], []),
    ("plenoxels", ["gray"], []),  # stage 2's losses need image batches
    ("gs2d", ["gray", "color"], ["backbone.rasterizer=gsplat"]), ("gs3d", ["gray", "color"], ["backbone.rasterizer=gsplat"]),
    ("gs2d", ["gray", "color"], ["backbone.rasterizer=triton"]),
    ("gs2d", ["gray", "color"], ["backbone.rasterizer=torch"])],  # (auto: triton on GPUs of 8.0 and newer)
    ids=["gs2d", "gs3d", "plenoxels", "gs2d-gsplat", "gs3d-gsplat", "gs2d-triton", "gs2d-torch"])
def test_stages_end_to_end_on_cuda(tmp_path, backbone, stages, extra):
    """``device=cuda``: every stage completes (Plenoxels: stage 1), also on gsplat's rasterisers and the Triton
    compositing, and the checkpoint
    written from the GPU loads on a machine without one (tensors mapped to the CPU)."""
    from arcsem import app
    from arcsem.train.checkpoint import load_checkpoint

    scene = write_transforms_scene(tmp_path / "scene", n=4, w=32, h=24)
    cv2.imwrite(str(tmp_path / "view_01.png"), np.full((24, 32, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", f"stage={'all' if len(stages) == 2 else 'gray'}", f"backbone={backbone}",
                       "device=cuda", "act=paper", "train.width=null", "train.steps=20", "train.eval.lpips=false",
                       "train.progress=false", "colorize.steps=5", "colorize.progress=false",
                       "colorize.eval.lpips=false", "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0",
                       f"colorize.references={tmp_path / 'view_01.png'}", f"cache_dir={tmp_path / 'cache'}",
                       "mesh.enabled=false", *extra)
    metrics = app.run(cfg, run_dir=tmp_path / "run")
    assert metrics["status"] == "complete" and metrics["completed_stages"] == stages
    assert np.isfinite(metrics["stage1"]["train"]["psnr"])
    if "color" in stages:
        assert metrics["stage2"]["steps"] == 5 and np.isfinite(metrics["stage2"]["final_loss"])
    state = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt", map_location="cpu")
    tensors = [v for v in state["model"].values() if isinstance(v, torch.Tensor)]
    assert tensors and all(t.device.type == "cpu" for t in tensors)



def test_a_cuda_run_resumes(tmp_path):
    """The same command again resumes a CUDA run from its checkpoint (RNG and sampler states are CPU tensors
    whatever device the checkpoint was mapped to: the first resumed CUDA runs stopped with 'RNG state must be a
    torch.ByteTensor')."""
    from arcsem import app

    scene = write_transforms_scene(tmp_path / "scene", n=4, w=32, h=24)
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=gray", "backbone=gs2d",
                       "device=cuda", "act=paper", "train.width=null", "train.steps=20", "train.eval.lpips=false",
                       "train.progress=false", f"cache_dir={tmp_path / 'cache'}", "mesh.enabled=false")
    first = app.run(cfg, run_dir=tmp_path / "run")
    again = app.run(cfg, run_dir=tmp_path / "run")
    assert first["status"] == again["status"] == "complete"
    assert again["stage1"]["resumed_from"] == 20
