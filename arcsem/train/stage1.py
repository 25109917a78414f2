"""Stage 1: train a backbone (+ ACT) on the grey views, evaluate it, write renders and the model.

``run_stage1(cfg, scene, run_dir)`` is what ``arcsem stage=gray`` runs (``arcsem/app.py`` writes the
returned dict into ``metrics.json``). It writes into ``run_dir``:

* ``checkpoints/last.pt``: the stage-1 checkpoint (resumed automatically, see ``train.resume``);
  :func:`arcsem.runs.load_stage1` rebuilds ``(backbone, act)`` from it for the colourisation stage;
* ``model.ply`` (Gaussians) / ``model.npz`` (grids): ``backbone.export``;
* ``mesh.ply`` / ``mesh.glb`` (TSDF fusion, ``mesh`` config) and ``viewer/`` (Gaussians: the folder
  layout 3DGS viewers load): :func:`arcsem.train.products.write_products`;
* ``views.csv``, ``renders/{train,test}/<name>.png`` and ``<name>_depth.png``, ``turntable.mp4``
  (``.gif`` without ffmpeg), ``train_history.csv``.

The ``train`` config group (``conf/train/*.yaml``) is validated against :class:`TrainConfig`. A preset adapts to
a backbone through Hydra's composition (``conf/tuning/<train>_<backbone>.yaml``), so the command line always wins;
a loss set to ``null`` in ``train.losses`` is off.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch

from ..configs import EvalConfig, TrainConfig
from ..metrics import metric_convention
from ..registry import plain
from ..runconfig import run_config
from ..scene import Scene
from ..timing import phase
from ..video import write_video
from ..visual import DEPTH_SPAN, to_uint8
from .evaluate import PROTOCOLS, evaluate_split, mean_metrics, resolve_protocol, write_views_csv
from .loop import LoopConfig, train
from .losses import build_losses
from .products import write_products
from .sampling import resize_scene
from .trend import loss_trend_warning

__all__ = [
    "NON_SEMANTIC_KEYS",
    "EvalConfig",
    "TrainConfig",
    "act_config",
    "backbone_config",
    "build_model",
    "evaluate",
    "prepare_scene",
    "run_stage1",
    "stage1_config",
    "stage1_losses",
    "train_config",
]

log = logging.getLogger(__name__)

NON_SEMANTIC_KEYS = ("resume", "eval_every", "log_every", "checkpoint_every", "progress", "eval")
"""``train`` keys that do not change the trained model (ignored when deciding whether to resume)."""


def train_config(cfg: Any) -> TrainConfig:
    """The validated ``train`` group of ``cfg`` (a run's :class:`~arcsem.runconfig.RunConfig`: validated once)."""
    return run_config(cfg).train


def stage1_config(cfg: Any, scene: Scene | None = None) -> dict:
    """The part of ``cfg`` that determines the stage-1 model (compared when resuming), with the dataset's
    :func:`~arcsem.scene.scene_fingerprint` when ``scene`` is given (stage 2 checks it)."""
    cfg = run_config(cfg).cfg
    train = {k: v for k, v in dict(plain(cfg.train) or {}).items() if k not in NON_SEMANTIC_KEYS}
    out = {"dataset": plain(cfg.get("dataset")), "backbone": plain(cfg.backbone), "act": plain(cfg.get("act")),
           "train": train, "seed": int(cfg.get("seed", 0))}
    if scene is not None:
        from ..scene import scene_fingerprint

        out["dataset_fingerprint"] = scene_fingerprint(scene)
    return out


def prepare_scene(scene: Scene, tc: TrainConfig) -> Scene:
    """The scene at the training resolution (both splits resized alike)."""
    return resize_scene(scene, tc.downscale, tc.width)


def act_config(cfg: Any):
    """The validated ``act`` group (:class:`arcsem.configs.ActConfig`)."""
    return run_config(cfg).act


def backbone_config(cfg: Any):
    """``cfg.backbone`` checked against the plugin's ``Config`` (ranges too): that ``Config`` instance."""
    return run_config(cfg).backbone


def stage1_losses(cfg: Any, tc: TrainConfig, act: Any = None):
    """The stage-1 :class:`LossSet` for ``cfg.backbone`` (checked against the plugin's outputs).

    ``act``: the ACT module, or True to stand for one (validation before the scene is known)."""
    from ..act import ACT

    rc = run_config(cfg)
    name, cls = rc.backbone_name, rc.backbone_class
    if act is True:
        act = ACT(1)
    return build_losses(tc.losses, cls.provides, cls.batch_mode, backbone=name, act=act or None,
                        validated=rc.loss_configs("train.losses"))


def build_model(cfg: Any, scene: Scene, tc: TrainConfig | None = None):
    """``(backbone, act)`` as configured, on ``cfg.device`` (``tc``: not needed; accepted for older callers)."""
    import copy

    from ..act import ACT

    rc = run_config(cfg)
    config, ac = rc.backbone, rc.act
    act = None
    if ac.enabled:
        act = ACT(len(scene.train), ac.mode, ac.init_noise)
    # a copy: the model owns its Config (a second model of this run starts from the same settings)
    backbone = rc.backbone_class(copy.deepcopy(config), scene=scene, **({"act": act} if act is not None else {}))
    device = torch.device(rc.device)
    return backbone.to(device), (act.to(device) if act is not None else None)


def _periodic_eval(backbone, scene: Scene, ec: EvalConfig):
    split, name = (scene.test, "test") if len(scene.test) else (scene.train, "train")

    def fn(step: int) -> dict:
        _, summary, _ = evaluate_split(backbone, split, split_name=name, length_scale=scene.scale[0], with_lpips=False,
                                       max_views=ec.periodic_views, metrics=ec.metrics)
        return {f"{name}_{k}": summary[k] for k in ("psnr", "ssim", "depth_mae_pct") if k in summary}
    return fn


def run_stage1(cfg: Any, scene: Scene, run_dir: str | Path) -> dict:
    """Train, evaluate and export stage 1; returns ``{"stage1": {...}}`` for ``metrics.json``."""
    run_dir = Path(run_dir)
    rc = run_config(cfg)
    cfg, tc = rc.cfg, rc.train
    timings: dict[str, float] = {}
    with phase(timings, "prepare"):
        raw_scene, scene = scene, prepare_scene(scene, tc)
        backbone, act = build_model(rc, scene)
        name = backbone.name
        losses = stage1_losses(rc, tc, act)
    rays = tc.rays_per_batch or int(backbone.rays_per_step)
    loop = LoopConfig(steps=tc.steps, stage="geometry", batch_views=tc.batch_views, rays_per_batch=rays,
                      log_every=tc.log_every, eval_every=tc.eval_every, checkpoint_every=tc.checkpoint_every,
                      resume=tc.resume, seed=int(cfg.get("seed", 0)), progress=tc.progress, desc=f"stage 1 ({name})")
    act_lr = rc.act.lr
    with phase(timings, "train"):
        res = train(backbone, scene.train, losses, loop, optim=tc.optim, ckpt_dir=run_dir / "checkpoints",
                    config=stage1_config(cfg, raw_scene), act=act, act_lr=act_lr,
                    evaluate=_periodic_eval(backbone, scene, tc.eval) if tc.eval_every else None)
    _write_history(run_dir / "train_history.csv", res.history)
    warning = loss_trend_warning(res.history, loop.desc)
    if warning:
        log.warning(warning)
    backbone.eval()
    with phase(timings, "evaluate"):  # metrics, renders, the orbit video
        result = evaluate(backbone, scene, run_dir, tc.eval, progress=tc.progress)
    with phase(timings, "export"):
        export = _export(backbone, run_dir)
    with phase(timings, "products"):  # the mesh and the viewer
        result.update(write_products(rc, backbone, scene, run_dir, iteration=res.steps, progress=tc.progress))
    return {"timings": timings, "stage1": {**result, "steps": res.steps, "time_s": res.time_s, "steps_per_s": res.steps_per_s,
                       "resumed_from": res.resumed_from, "num_primitives": int(backbone.num_primitives()),
                       "image_size": [scene.train.cameras.width, scene.train.cameras.height],
                       "losses": sorted(losses.terms), "checkpoint": str(res.checkpoint), "export": export,
                       "periodic": res.evals, "final_loss": res.history[-1]["loss"] if res.history else None,
                       "warnings": [warning] if warning else []}}


def evaluate(backbone, scene: Scene, run_dir: str | Path | None, ec: EvalConfig | None = None,
             progress: bool = False) -> dict:
    """Final evaluation, two protocols (:data:`~arcsem.train.evaluate.PROTOCOLS`, recorded as ``protocols``):

    * ``train_paper``: training views, each with its own ACT, against the observed images (the paper's Table 1);
    * ``train`` and ``test``: training and held-out views as ``auto`` scores them: the mean ACT against the
      noise-free images where the dataset has them (the synthetic scenes), else as ``train_paper``;
    plus depth error, per-view CSV, renders and the turntable video (``progress``: tqdm bars for each).
    """
    ec = ec or EvalConfig()
    out_dir = Path(run_dir) if run_dir is not None and ec.renders else None
    rows, result, depth, protocols = [], {}, {}, {}
    passes = [(scene.train, "train", ec.max_train_views, "auto", out_dir), (scene.test, "test", None, "auto", out_dir)]
    if scene.train.clean is not None:  # the paper's protocol differs from "auto" only where clean images exist
        passes.insert(1, (scene.train, "train_paper", ec.max_train_views, "paper", None))
    for split, sname, limit, protocol, where in passes:
        if len(split) == 0:
            result[sname] = {}
            continue
        r, summary, _ = evaluate_split(backbone, split, split_name=sname, length_scale=scene.scale[0], out_dir=where,
                                       with_lpips=ec.lpips and (ec.lpips_splits == "all" or sname == "test"),
                                       max_views=limit, protocol=protocol, metrics=ec.metrics,
                                       progress=progress)
        rows += r
        for k in ("depth_mae", "depth_mae_pct"):
            if k in summary and sname != "train_paper":
                depth[f"{sname}_{k[6:]}"] = summary.pop(k)
        weights = summary.pop("lpips_weights")
        if weights != "skipped" or "lpips_weights" not in result:  # a split LPIPS skipped says nothing of the weights
            result["lpips_weights"] = weights
        result[sname] = summary
        protocols[sname] = PROTOCOLS[resolve_protocol(split, protocol)]
    if "train_paper" not in result and "train" in result:
        result["train_paper"], protocols["train_paper"] = result["train"], protocols.get("train")
    result["protocols"] = protocols
    result["metrics_convention"] = metric_convention(ec.metrics)
    result["lpips_splits"] = ec.lpips_splits
    if depth:
        source = "median_depth" if "median_depth" in backbone.provides else "depth"
        depth.update(length_scale=scene.scale[0], length_scale_name=scene.scale[1], source=source,
                     micrometres_per_unit=scene.micrometres_per_unit, display_span=DEPTH_SPAN * scene.scale[0])
    result["depth"] = depth
    auto_rows = [r for r in rows if r["split"] != "train_paper"]  # each view once
    result["all_views"] = mean_metrics(auto_rows) if auto_rows else {}
    if run_dir is not None:
        write_views_csv(Path(run_dir) / "views.csv", rows)
        if ec.video:
            result["video"] = str(turntable(backbone, scene, Path(run_dir) / "turntable", ec.video_frames, ec.fps,
                                            progress=progress))
    return result


def turntable(backbone, scene: Scene, path: Path, frames: int = 60, fps: int = 20, progress: bool = False) -> Path:
    """Render ``frames`` novel views on a full orbit around the specimen (mean ACT; :mod:`arcsem.orbit`,
    20 degrees above the orbit plane) and write a video (``progress``: a tqdm bar over the frames)."""
    from tqdm import tqdm

    from ..orbit import OrbitConfig, orbit_cameras

    cams = orbit_cameras(scene.train.cameras, scene.bounds, OrbitConfig(frames=frames))
    images = []
    with torch.no_grad():
        for k in tqdm(range(frames), desc=f"{path.name}: rendering", disable=not progress, leave=False):
            images.append(to_uint8(backbone.render(cams[k : k + 1])["rgb"][0].cpu()))
    return write_video(path, images, fps)


def _export(backbone, run_dir: Path) -> str | None:
    path = run_dir / f"model{backbone.export_suffix}"
    try:
        backbone.export(str(path))
    except NotImplementedError:
        return None
    return str(path)


def _write_history(path: Path, history: list[dict]) -> None:
    if history:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_views_csv(path, history)
