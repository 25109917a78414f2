"""Training: the generic loop (stage 1 and 2), optimisers, samplers, loss sets, checkpoints, evaluation.

``run_stage1(cfg, scene, run_dir)`` trains and evaluates stage 1; ``train(...)`` is the loop the
colourisation stage reuses (``stage="color"``, its own losses and ``batch_hook``); :func:`arcsem.runs.load_stage1`
rebuilds a trained ``(backbone, act)`` from ``run_dir/checkpoints/last.pt``.
"""
from .checkpoint import load_checkpoint, save_checkpoint
from .evaluate import evaluate_split
from .loop import LoopConfig, TrainResult, render_batch, train
from .losses import LossSet, build_losses
from .optim import GroupSchedule, OptimConfig
from .stage1 import EvalConfig, TrainConfig, build_model, evaluate, prepare_scene, run_stage1

__all__ = [
    "EvalConfig",
    "GroupSchedule",
    "LoopConfig",
    "LossSet",
    "OptimConfig",
    "TrainConfig",
    "TrainResult",
    "build_losses",
    "build_model",
    "evaluate",
    "evaluate_split",
    "load_checkpoint",
    "prepare_scene",
    "render_batch",
    "run_stage1",
    "save_checkpoint",
    "train",
]
