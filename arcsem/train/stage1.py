"""Stage 1: train a backbone (+ ACT) on the grey views, evaluate it, write renders and the model.

``run_stage1(cfg, scene, run_dir)`` is what ``arcsem stage=gray`` runs (``arcsem/app.py`` writes the
returned dict into ``metrics.json``). It writes into ``run_dir``:

* ``checkpoints/last.pt``: the stage-1 checkpoint (resumed automatically, see ``train.resume``);
  :func:`load_stage1` rebuilds ``(backbone, act)`` from it for the colourisation stage;
* ``model.ply`` (Gaussians) / ``model.npz`` (grids): ``backbone.export``;
* ``mesh.ply`` / ``mesh.glb`` (TSDF fusion, ``mesh`` config) and ``viewer/`` (Gaussians: the folder
  layout 3DGS viewers load): :func:`arcsem.train.products.write_products`;
* ``views.csv``, ``renders/{train,test}/<name>.png`` and ``<name>_depth.png``, ``turntable.mp4``
  (``.gif`` without ffmpeg), ``train_history.csv``.

The ``train`` config group (``conf/train/*.yaml``) is validated against :class:`TrainConfig`.
``per_backbone.<name>`` adapts a preset to a backbone: ``backbone`` keys merged into
``cfg.backbone`` (e.g. a shortened densification schedule), ``losses`` merged into
``losses`` (``null`` removes a term) and ``steps`` (a backbone whose step costs more), so one
preset serves every backbone of a sweep.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf

from ..errors import ConfigError, TrainingError
from ..plugins import BACKBONES
from ..registry import validate_config
from ..scene import Scene
from .checkpoint import load_checkpoint, load_module_state
from .evaluate import DEPTH_SPAN, evaluate_split, mean_metrics, to_uint8, write_views_csv
from .loop import LoopConfig, train
from .losses import build_losses, merge_loss_cfgs
from .optim import OptimConfig
from .products import write_products
from .sampling import resize_split
from .video import write_video

__all__ = [
    "NON_SEMANTIC_KEYS",
    "EvalConfig",
    "TrainConfig",
    "build_model",
    "evaluate",
    "load_stage1",
    "prepare_scene",
    "run_stage1",
    "stage1_config",
]

NON_SEMANTIC_KEYS = ("resume", "eval_every", "log_every", "checkpoint_every", "progress", "eval")
"""``train`` keys that do not change the trained model (ignored when deciding whether to resume)."""


@dataclass
class EvalConfig:
    """``train.eval``: what the final and periodic evaluations do."""

    lpips: bool = True  # LPIPS (AlexNet); NaN + reason when its ImageNet weights are missing
    renders: bool = True  # write renders/{train,test}/<name>.png and <name>_depth.png
    video: bool = True  # turntable.mp4: novel views on a full orbit around the specimen
    video_frames: int = 60
    fps: int = 20
    max_train_views: int | None = None  # score at most this many training views (None: all, the paper)
    periodic_views: int = 4  # views scored (PSNR/SSIM) at every periodic evaluation


@dataclass
class TrainConfig:
    """``train``: the stage-1 preset (see conf/train/quick.yaml and paper.yaml)."""

    steps: int = 60_000  # ArCSEM stage 1
    batch_views: int = 1  # views per step (image backbones)
    rays_per_batch: int | None = None  # ray backbones; None: the backbone's batch_size, else 5000
    downscale: float = 1.0  # training/evaluation images at 1/downscale of the dataset resolution
    width: int | None = None  # or: resize to this width (overrides downscale)
    log_every: int = 100
    eval_every: int = 0  # periodic evaluation (0: only the final one)
    checkpoint_every: int = 5000
    resume: str = "auto"  # auto | never | must
    progress: bool = True
    losses: dict[str, Any] = field(default_factory=lambda: {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}})
    optim: OptimConfig = field(default_factory=OptimConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    per_backbone: dict[str, Any] = field(default_factory=dict)  # name -> {backbone: {...}, losses: {...}, steps: n}


def _plain(x: Any) -> Any:
    return OmegaConf.to_container(x, resolve=True) if isinstance(x, DictConfig) else x


def train_config(cfg: Any) -> TrainConfig:
    return validate_config(TrainConfig, dict(_plain(cfg.train) or {}), where="train")


def stage1_config(cfg: Any) -> dict:
    """The part of ``cfg`` that determines the stage-1 model (compared when resuming)."""
    train = {k: v for k, v in dict(_plain(cfg.train) or {}).items() if k not in NON_SEMANTIC_KEYS}
    return {"dataset": _plain(cfg.get("dataset")), "backbone": _plain(cfg.backbone), "act": _plain(cfg.get("act")),
            "train": train, "seed": int(cfg.get("seed", 0))}


def prepare_scene(scene: Scene, tc: TrainConfig) -> Scene:
    """The scene at the training resolution (both splits resized alike)."""
    return dataclasses.replace(scene, train=resize_split(scene.train, tc.downscale, tc.width),
                               test=resize_split(scene.test, tc.downscale, tc.width))


ACT_KEYS = {"enabled", "mode", "lr", "init_noise", "solver", "fit_rate", "fit_prior", "smooth_degree"}  # conf/act


def build_model(cfg: Any, scene: Scene, tc: TrainConfig | None = None):
    """``(backbone, act)`` as configured (``per_backbone`` overrides applied), on ``cfg.device``."""
    from ..act import ACT

    tc = tc or train_config(cfg)
    bcfg = dict(_plain(cfg.backbone))
    bcfg.update((tc.per_backbone.get(bcfg["name"]) or {}).get("backbone") or {})
    act_cfg = _plain(cfg.get("act")) or {}
    unknown = set(act_cfg) - ACT_KEYS
    if unknown:
        raise ConfigError(f"act: unknown key(s) {sorted(unknown)}; valid: {', '.join(sorted(ACT_KEYS))}")
    act = None
    if act_cfg.get("enabled", False):
        act = ACT(len(scene.train), act_cfg.get("mode", "rgb"), float(act_cfg.get("init_noise", 1e-3)),
                  act_cfg.get("solver", "adam"), float(act_cfg.get("fit_rate", 0.5)), float(act_cfg.get("fit_prior", 0.0)),
                  view_dirs=scene.train.cameras.forward, smooth_degree=int(act_cfg.get("smooth_degree", -1)))
    backbone = BACKBONES.build(bcfg, scene=scene, **({"act": act} if act is not None else {}))
    device = torch.device(str(cfg.get("device", "cpu")))
    return backbone.to(device), (act.to(device) if act is not None else None)


def _periodic_eval(backbone, scene: Scene, ec: EvalConfig):
    split, name = (scene.test, "test") if len(scene.test) else (scene.train, "train")

    def fn(step: int) -> dict:
        _, summary, _ = evaluate_split(backbone, split, split_name=name, length_scale=scene.scale[0], with_lpips=False,
                                       max_views=ec.periodic_views)
        return {f"{name}_{k}": summary[k] for k in ("psnr", "ssim", "depth_mae_pct") if k in summary}
    return fn


def run_stage1(cfg: Any, scene: Scene, run_dir: str | Path) -> dict:
    """Train, evaluate and export stage 1; returns ``{"stage1": {...}}`` for ``metrics.json``."""
    run_dir = Path(run_dir)
    tc = train_config(cfg)
    scene = prepare_scene(scene, tc)
    backbone, act = build_model(cfg, scene, tc)
    name = backbone.name
    losses = build_losses(merge_loss_cfgs(tc.losses, (tc.per_backbone.get(name) or {}).get("losses")),
                          backbone.provides, backbone.batch_mode, backbone=name, act=act)
    rays = tc.rays_per_batch or int(getattr(backbone.cfg, "batch_size", 5000))
    over = tc.per_backbone.get(name) or {}
    unknown = set(over) - {"backbone", "losses", "steps"}
    if unknown:
        raise ConfigError(f"train.per_backbone.{name}: unknown key(s) {sorted(unknown)}; valid: backbone, losses, steps")
    loop = LoopConfig(steps=int(over.get("steps", tc.steps)), stage="geometry", batch_views=tc.batch_views, rays_per_batch=rays,
                      log_every=tc.log_every, eval_every=tc.eval_every, checkpoint_every=tc.checkpoint_every,
                      resume=tc.resume, seed=int(cfg.get("seed", 0)), progress=tc.progress, desc=f"stage 1 ({name})")
    act_lr = float((_plain(cfg.get("act")) or {}).get("lr", 1e-4))
    res = train(backbone, scene.train, losses, loop, optim=tc.optim, ckpt_dir=run_dir / "checkpoints",
                config=stage1_config(cfg), act=act, act_lr=act_lr,
                evaluate=_periodic_eval(backbone, scene, tc.eval) if tc.eval_every else None)
    _write_history(run_dir / "train_history.csv", res.history)
    backbone.eval()
    result = evaluate(backbone, scene, run_dir, tc.eval)
    export = _export(backbone, run_dir)
    result.update(write_products(cfg, backbone, scene, run_dir, iteration=res.steps, progress=tc.progress))
    return {"stage1": {**result, "steps": res.steps, "time_s": res.time_s, "steps_per_s": res.steps_per_s,
                       "resumed_from": res.resumed_from, "num_primitives": int(backbone.num_primitives()),
                       "image_size": [scene.train.cameras.width, scene.train.cameras.height],
                       "losses": sorted(losses.terms), "checkpoint": str(res.checkpoint), "export": export,
                       "periodic": res.evals, "final_loss": res.history[-1]["loss"] if res.history else None}}


def evaluate(backbone, scene: Scene, run_dir: str | Path | None, ec: EvalConfig | None = None) -> dict:
    """Final evaluation: train views (own ACT) and test views (mean ACT), depth, CSV, renders, video."""
    ec = ec or EvalConfig()
    out_dir = Path(run_dir) if run_dir is not None and ec.renders else None
    rows, result, depth = [], {}, {}
    for split, sname, limit in ((scene.train, "train", ec.max_train_views), (scene.test, "test", None)):
        if len(split) == 0:
            result[sname] = {}
            continue
        r, summary, _ = evaluate_split(backbone, split, split_name=sname, length_scale=scene.scale[0], out_dir=out_dir,
                                       with_lpips=ec.lpips, max_views=limit)
        rows += r
        for k in ("depth_mae", "depth_mae_pct"):
            if k in summary:
                depth[f"{sname}_{k[6:]}"] = summary.pop(k)
        result["lpips_weights"] = summary.pop("lpips_weights")
        result[sname] = summary
    if depth:
        source = "median_depth" if "median_depth" in backbone.provides else "depth"
        depth.update(length_scale=scene.scale[0], length_scale_name=scene.scale[1], source=source,
                     micrometres_per_unit=scene.micrometres_per_unit, display_span=DEPTH_SPAN * scene.scale[0])
    result["depth"] = depth
    result["all_views"] = mean_metrics(rows) if rows else {}
    if run_dir is not None:
        write_views_csv(Path(run_dir) / "views.csv", rows)
        if ec.video:
            result["video"] = str(turntable(backbone, scene, Path(run_dir) / "turntable", ec.video_frames, ec.fps))
    return result


def turntable(backbone, scene: Scene, path: Path, frames: int = 60, fps: int = 20) -> Path:
    """Render ``frames`` novel views on a full orbit around the specimen (mean ACT; :mod:`arcsem.orbit`,
    20 degrees above the orbit plane) and write a video."""
    from ..orbit import OrbitConfig, orbit_cameras

    cams = orbit_cameras(scene.train.cameras, scene.bounds, OrbitConfig(frames=frames))
    images = []
    with torch.no_grad():
        for k in range(frames):
            images.append(to_uint8(backbone.render(cams[k : k + 1])["rgb"][0].cpu()))
    return write_video(path, images, fps)


def _export(backbone, run_dir: Path) -> str | None:
    suffix = getattr(backbone, "export_suffix", None) or (".npz" if backbone.batch_mode == "rays" else ".ply")
    path = run_dir / f"model{suffix}"
    try:
        backbone.export(str(path))
    except NotImplementedError:
        return None
    return str(path)


def _write_history(path: Path, history: list[dict]) -> None:
    if history:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_views_csv(path, history)


def load_stage1(path: str | Path, scene: Scene, cfg: Any = None):
    """Rebuild ``(backbone, act)`` from a stage-1 checkpoint (``run_dir/checkpoints/last.pt``).

    The backbone and ACT are built from the config stored in the checkpoint (``cfg`` is used only for
    ``device`` and for checkpoints without a stored config); ``scene`` provides the training cameras.
    Returns the models in eval mode; ``act`` is None when stage 1 ran without ACT.
    """
    state = load_checkpoint(path)
    saved = state.get("config") or {}
    if not saved.get("backbone") and cfg is None:
        raise TrainingError(f"{path}: checkpoint has no stored config; pass the stage-1 cfg")
    base = OmegaConf.create({**(saved or stage1_config(cfg)), "device": str((cfg or {}).get("device", "cpu"))})
    tc = train_config(base)
    backbone, act = build_model(base, prepare_scene(scene, tc), tc)
    load_module_state(backbone, state["model"])
    if act is not None and state.get("act") is not None:
        load_module_state(act, state["act"])
    backbone.eval()
    return backbone, act
