"""A finished run folder with a known model, laid out as ``arcsem`` writes one (``config.yaml``,
``checkpoints/last.pt`` and, optionally, the stage-2 ``colorize/checkpoints/last.pt``): Gaussians on
a sphere of radius ``R`` around the origin, red for x > 0 and green for x < 0 (the coloured model:
blue and yellow), on a tiny ``transforms.json`` scene. The loaders read it like any trained run."""
from __future__ import annotations

import math
from pathlib import Path

import torch
from conftest import write_transforms_scene
from omegaconf import OmegaConf

R = 0.5


def sphere_params(n: int = 3000, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """``[n, 3]`` Fibonacci points on the sphere and their colours ``[n, 3]``."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = torch.sqrt(1 - z**2)
    pts = R * torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
    cols = torch.where(pts[:, :1] > 0, torch.tensor([[0.9, 0.1, 0.1]], dtype=torch.float64),
                       torch.tensor([[0.1, 0.8, 0.1]], dtype=torch.float64))
    return pts.float(), cols.float()


def _set_sphere(backbone, colours: torch.Tensor) -> None:
    from arcsem.backbones.sh import rgb_to_sh

    pts, _ = sphere_params()
    m = backbone.model
    n = len(pts)
    normal = pts / pts.norm(dim=-1, keepdim=True)
    # rotation whose third axis is the outward normal (surfels lie in the tangent plane)
    z = torch.tensor([0.0, 0.0, 1.0])
    axis = torch.linalg.cross(z.expand(n, 3), normal)
    s = axis.norm(dim=-1, keepdim=True)
    c = (normal * z).sum(-1, keepdim=True)
    half = torch.atan2(s, c) / 2
    axis = torch.where(s > 1e-6, axis / s.clamp_min(1e-12), torch.tensor([1.0, 0.0, 0.0]))
    quats = torch.cat([torch.cos(half), axis * torch.sin(half)], -1)
    k = m.log_scales.shape[1]
    params = {"means": pts, "quats": quats, "log_scales": torch.full((n, k), math.log(0.03)),
              "opacity_logits": torch.full((n,), 4.0), "sh_dc": rgb_to_sh(colours)[:, None, :],
              "sh_rest": torch.zeros(n, m.sh_rest.shape[1], 3)}
    m.set_params(params)


def make_run(root: Path, backbone: str = "gs2d", colored: bool = True, camera: str | None = None) -> Path:
    """Write the scene under ``root/scene`` and the run folder ``root/run``; returns the run folder."""
    from test_config import compose_with

    from arcsem.data import load_scene
    from arcsem.train.checkpoint import save_checkpoint
    from arcsem.train.stage1 import build_model, prepare_scene, stage1_config, train_config

    top = {"aabb": [[-0.6] * 3, [0.6] * 3]}
    if camera == "orthographic":
        top["camera_model"] = "ORTHOGRAPHIC"
    path = write_transforms_scene(root / "scene", n=6, w=40, h=30, fl=80.0 if camera != "orthographic" else 20.0,
                                  **top)
    cfg = compose_with("dataset=transforms", f"dataset.path={path.parent}", f"backbone={backbone}", "act=none",
                       "train.width=null", "train.downscale=1", "train.steps=10")
    run = root / "run"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    scene = prepare_scene(load_scene(cfg.dataset), train_config(cfg))
    model, _ = build_model(cfg, scene)
    _set_sphere(model, sphere_params()[1])
    save_checkpoint(run / "checkpoints" / "last.pt", {"step": 10, "model": model.state_dict(),
                                                      "config": stage1_config(cfg)})
    if colored:
        pts = sphere_params()[0]
        _set_sphere(model, torch.where(pts[:, :1] > 0, torch.tensor([[0.1, 0.2, 0.9]]), torch.tensor([[0.9, 0.8, 0.1]])))
        save_checkpoint(run / "colorize" / "checkpoints" / "last.pt", {"step": 5, "model": model.state_dict()})
    return run
