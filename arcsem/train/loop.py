"""The generic training loop shared by stage 1 (grey geometry) and stage 2 (colour).

One step: set the scheduled learning rates, draw a batch (whole views or random rays), let the
stage's ``batch_hook`` add its targets (stage 2: ``batch.color``), render, sum the active loss terms, call
``backbone.pre_backward``, backpropagate, call ``backbone.post_backward`` (densify, prune, upsample: it
may replace tensors in ``optimizers[group]``), step every optimiser and note whether the loss terms and
parameters are finite. The notes stay on the model's device and are read every step on the CPU, every
``log_every`` steps on a GPU (a read is a host synchronisation), and before anything is written: any non-finite
loss term, gradient or parameter stops the run with a :class:`TrainingError` that names the first step, the term
or group, and the checkpoint actually on disk (or that there is none); nothing is written after the failure.

Checkpoints go to ``ckpt_dir/last.pt`` every ``checkpoint_every`` steps and at the end. With
``resume="auto"`` an existing checkpoint whose config matches is continued (announced on the console
and in the log); ``"must"`` requires one; ``"never"`` starts over. Ctrl-C stops after the step in
progress, writes a checkpoint and raises :class:`~arcsem.errors.Interrupted`; a second Ctrl-C stops at
once. Evaluation and checkpointing run under a forked RNG, so how often they happen does not change
the trained model.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn
from tqdm.auto import tqdm

from ..errors import ConfigError, Interrupted, TrainingError
from ..plugins import Batch, RenderOutput
from ..registry import checked, validate_config
from ..scene import Split
from ..timing import region
from . import checkpoint as ckpt
from .frozen import FrozenViews
from .interrupt import StopRequest
from .losses import LossSet
from .optim import OptimConfig, apply_schedules, group_schedules, make_optimizers
from .sampling import make_sampler

log = logging.getLogger(__name__)

__all__ = ["LoopConfig", "TrainResult", "render_batch", "train"]


@dataclass
class LoopConfig:
    """How long and how a stage trains (the trainer keys of a ``train``/``colorize`` preset)."""

    steps: int = checked(ge=1)
    stage: str = checked("geometry", choices=("geometry", "color"))  # passed to backbone.param_groups
    batch_views: int = checked(1, ge=1)  # views per step (image backbones)
    rays_per_batch: int = checked(5000, ge=1)  # rays per step (ray backbones; svox2's default)
    log_every: int = checked(100, ge=1)  # progress-bar / history interval (steps)
    eval_every: int = checked(0, ge=0)  # evaluation interval (0: only at the end, done by the caller)
    checkpoint_every: int = checked(1000, ge=0)  # checkpoint interval (0: only at the end)
    # finiteness read back every this many steps (0: every step on the CPU, log_every on a GPU; see _Health)
    check_every: int = checked(0, ge=0)
    # stage "color": memory (MiB) for the views' frozen-geometry renders (Backbone.colour_operator; 0: never)
    frozen_mb: int = checked(0, ge=0)
    resume: str = checked("auto", choices=("auto", "never", "must"))
    seed: int = 0
    progress: bool = True  # show a tqdm bar
    desc: str = "train"  # progress-bar label


@dataclass
class TrainResult:
    steps: int  # completed steps
    time_s: float  # training time (steps only, summed over resumed segments)
    resumed_from: int | None  # step the run continued from, or None
    checkpoint: Path | None
    history: list[dict] = field(default_factory=list)  # every log_every steps: step, loss, psnr, terms
    evals: list[dict] = field(default_factory=list)  # results of the periodic evaluation callback
    frozen: dict | None = None  # stage 2's recorded renders (FrozenViews.summary), None where not used

    @property
    def steps_per_s(self) -> float:
        return self.steps / self.time_s if self.time_s > 0 else float("nan")


def render_batch(backbone: nn.Module, batch: Batch) -> RenderOutput:
    """Render a batch: ``render_rays`` for ray batches, ``render`` for whole views."""
    if batch.rays_o is not None:
        return backbone.render_rays(batch.rays_o, batch.rays_d, batch.ray_image_ids)
    return backbone.render(batch.cameras)


def _groups(backbone: nn.Module, act: nn.Module | None, stage: str) -> dict[str, list[nn.Parameter]]:
    groups = {g: list(ps) for g, ps in backbone.param_groups(stage).items() if len(list(ps))}
    if act is not None:
        seen = {id(p) for ps in groups.values() for p in ps}
        extra = [p for p in act.parameters() if id(p) not in seen and p.requires_grad]
        if extra:
            groups["act"] = groups.get("act", []) + extra
    if not groups:
        raise ConfigError(f"backbone has no trainable parameters for stage '{stage}'")
    return groups


class _Health:
    """Whether every loss term and parameter of each step is finite, computed on the model's device and read back
    every ``every`` steps: 1 on the CPU, where a read costs nothing; ``log_every`` on a GPU, where each read is a
    host synchronisation. Also read before every checkpoint and evaluation, and at the end, so nothing is written
    after a failure. A parameter is checked by its norm (one multi-tensor pass over all of them; a non-finite element
    makes it non-finite); a norm that overflowed is told apart when read, element by element. A non-finite gradient makes its parameters
    non-finite in the optimiser step (Adam: m, v and the update), so gradients, the usual cause, are named when a
    parameter fails in the step just taken (they are gone by the next one)."""

    def __init__(self, every: int):
        self.every, self.names, self.first = every, (), None  # first: [K] long, first bad step of each slot (-1: none)
        self.step, self.params, self.grads = -1, [], {}

    def record(self, run: _Run, step: int, terms: Mapping[str, torch.Tensor], params: Mapping[str, list],
               grads: Mapping[str, list]) -> None:
        """Note the finiteness of ``terms`` (scalars) and ``params`` (per group) after 0-based ``step``; no host read."""
        names = tuple(("loss term", n, "loss") for n in terms) + tuple(
            ("parameter group", g, "after the optimiser step") for g, ps in params.items() for _ in ps)
        if names != self.names:  # the active terms or the groups changed: read what the old layout holds first
            self.read(run)
            self.names, self.first = names, None
        self.params = [p for ps in params.values() for p in ps]
        with torch.no_grad():  # a handful of operators whatever the number of terms and groups (a GPU's host issues each)
            values = torch.stack([*terms.values(), *torch._foreach_norm(self.params)]).float()
            start = torch.full(values.shape, -1, dtype=torch.long, device=values.device) if self.first is None \
                else self.first
            finite = values * 0 == 0  # as isfinite (NaN and inf times 0 are NaN) in 2 operators, not 4
            self.first = torch.where(finite | (start >= 0), start, step)
        self.step, self.grads = step, grads

    def due(self, step: int) -> bool:
        return (step + 1) % self.every == 0

    def read(self, run: _Run) -> None:
        """Raise :class:`TrainingError` naming the first step, term or group that was not finite (one host read)."""
        if self.first is None:
            return
        first, n_terms = self.first.tolist(), len(self.names) - len(self.params)
        bad = [(s, i) for i, s in enumerate(first) if s >= 0]
        for s, i in list(bad):  # a parameter whose norm overflowed while every element is finite
            if i >= n_terms and bool(torch.isfinite(self.params[i - n_terms]).all()):
                bad.remove((s, i))
                self.first[i] = -1
        if not bad:
            return
        step, i = min(bad)
        kind, name, what = self.names[i]
        if kind == "parameter group" and step == self.step:
            for g, gs in self.grads.items():
                if not all(t is None or bool(torch.isfinite(t._values() if t.is_sparse else t).all()) for t in gs):
                    kind, name, what = "gradient of group", g, "gradient"
                    break
        raise TrainingError(f"step {step + 1}: {kind} '{name}' is not finite ({what}); training stopped, "
                            f"{run.on_disk()}")


class _Run:
    """State of one training run (kept small so :func:`train` reads as the step sequence)."""

    def __init__(self, backbone, act, split, loop, optim, ckpt_dir, config):
        self.backbone, self.act, self.loop, self.config = backbone, act, loop, dict(config or {})
        self.path = Path(ckpt_dir) / "last.pt" if ckpt_dir is not None else None
        self.sampler = make_sampler(split, backbone.batch_mode, loop.batch_views,
                                    loop.rays_per_batch, loop.seed, _device(backbone))
        self.optim = optim
        self.step, self.time_s, self.history, self.evals, self.resumed_from = 0, 0.0, [], [], None
        self.loss_sum, self.loss_n = None, 0  # the loss summed on the device since the last logged step
        self.saved_step: int | None = None  # step of the checkpoint on disk (None: none written or loaded)
        self.act_separate = act is not None and not any(m is act for m in backbone.modules())
        self.health = _Health(loop.check_every or (1 if _device(backbone).type == "cpu" else loop.log_every))
        self.frozen = FrozenViews(loop.frozen_mb) if loop.stage == "color" and loop.frozen_mb else None

    def build_optimizers(self, act_lr: float | None) -> None:
        groups = _groups(self.backbone, self.act, self.loop.stage)
        self.schedules = group_schedules(groups, self.backbone, self.loop.stage, self.optim, act_lr)
        self.optimizers = make_optimizers(self.backbone, groups, self.schedules, self.optim, self.loop.stage)

    def state(self) -> dict:
        return {"step": self.step, "stage": self.loop.stage, "model": self.backbone.state_dict(),
                "act": self.act.state_dict() if self.act_separate else None,
                "optimizers": {g: o.state_dict() for g, o in self.optimizers.items()},
                "sampler": self.sampler.state_dict(), "rng": ckpt.rng_state(), "config": self.config,
                "config_hash": ckpt.config_hash(self.config), "time_s": self.time_s, "history": self.history,
                "evals": self.evals, "num_primitives": int(self.backbone.num_primitives())}

    def save(self) -> None:
        self.health.read(self)  # never a checkpoint of a model that is not finite
        if self.path is not None:
            with region("arcsem::checkpoint"):
                ckpt.save_checkpoint(self.path, self.state())
            self.saved_step = self.step

    def on_disk(self) -> str:
        """What a user can resume from, for messages: the checkpoint on disk, or that there is none."""
        if self.path is None:
            return "no checkpoints are written in this run"
        if self.saved_step is None:
            return f"no checkpoint has been written yet ({self.path} does not exist)"
        return f"the checkpoint on disk is from step {self.saved_step} ({self.path})"

    def restore(self, act_lr: float | None) -> None:
        """Load ``last.pt`` per ``loop.resume``; always leaves optimisers built."""
        mode = self.loop.resume
        if self.path is not None:
            for tmp in ckpt.remove_stale_temporaries(self.path):
                log.info("%s: removed %s, left by a checkpoint write that did not finish", self.loop.desc, tmp.name)
        if mode not in ("auto", "never", "must"):
            raise ConfigError(f"train.resume: '{mode}' is not one of auto, never, must")
        exists = self.path is not None and self.path.is_file()
        if mode == "must" and not exists:
            raise TrainingError(f"train.resume=must but there is no checkpoint at {self.path}")
        if mode == "never" or not exists:
            self.build_optimizers(act_lr)
            return
        state = ckpt.load_checkpoint(self.path, _device(self.backbone))
        ckpt.check_config(state["config"], self.config, self.path)
        ckpt.load_module_state(self.backbone, state["model"])
        if self.act_separate and state.get("act") is not None:
            ckpt.load_module_state(self.act, state["act"])
        self.build_optimizers(act_lr)
        if set(state["optimizers"]) != set(self.optimizers):
            raise TrainingError(f"cannot resume from {self.path}: it has parameter groups {sorted(state['optimizers'])}, "
                                f"this run has {sorted(self.optimizers)}")
        for g, o in self.optimizers.items():
            o.load_state_dict(state["optimizers"][g])
        self.sampler.load_state_dict(state["sampler"])
        ckpt.set_rng_state(state["rng"])
        self.step = self.resumed_from = self.saved_step = int(state["step"])
        self.time_s, self.history, self.evals = state["time_s"], state["history"], state["evals"]
        log.info("%s: resuming from step %d of %d (%s)", self.loop.desc, self.step, self.loop.steps, self.path)


def _device(backbone: nn.Module) -> torch.device:
    p = next(iter(backbone.parameters()), None)
    return p.device if p is not None else torch.device("cpu")


def _step(run: _Run, losses: LossSet, batch_hook, step: int, record: bool) -> dict | None:
    """One optimisation step; with ``record``, returns ``{loss, psnr, <term>: value}`` (one host read), else None.

    Nothing in a step waits for the device (the finiteness checks stay there: :class:`_Health`), except what a
    rasteriser must know of its data (tile lists) and densification's row counts.
    The parts run in named profiler regions (``arcsem::sample``, ``arcsem::render``, ...; free when no profiler
    runs): benchmarks/profile_step.py attributes time, backward passes included, to them."""
    bb = run.backbone
    run.health.grads = {}  # the last step's gradients: not kept alive through this one
    apply_schedules(run.optimizers, run.schedules, step, run.loop.steps, run.optim.lr_scale)
    with region("arcsem::sample"):
        batch = run.sampler.next()
        if batch_hook is not None:
            batch = batch_hook(batch)
    with region("arcsem::render"):
        out = run.frozen.render(bb, batch) if run.frozen is not None else None
        if out is None:
            out = render_batch(bb, batch)
    total, terms = losses(out, batch, step)
    run.loss_sum = total.detach() if run.loss_sum is None else run.loss_sum + total.detach()  # no host read
    run.loss_n += 1
    bb.pre_backward(step, out)
    with region("arcsem::backward"):
        bb.zero_grad(set_to_none=True)
        for o in run.optimizers.values():  # as o.zero_grad(set_to_none=True), without its profiler region's operators
            for pg in o.param_groups:
                for p in pg["params"]:
                    p.grad = None
        total.backward()
    params = {g: [p for pg in o.param_groups for p in pg["params"]] for g, o in run.optimizers.items()}
    grads = {g: [p.grad for p in ps] for g, ps in params.items()}
    bb.post_backward(step, out, run.optimizers)
    with region("arcsem::optimizer"):
        for o in run.optimizers.values():
            o.step()
    with region("arcsem::checks"):
        params = {g: [p for pg in o.param_groups for p in pg["params"]] for g, o in run.optimizers.items()}
        run.health.record(run, step, terms, params, grads)
        if run.health.due(step):
            run.health.read(run)
    if not record:
        return None
    mse = ((out["rgb"].detach() - batch.images) ** 2).mean()
    mean = run.loss_sum.float() / run.loss_n  # (reset by the loop at a logged step)
    values = torch.stack([total.detach().float(), mse.float(), mean, *(v.detach().float() for v in terms.values())])
    loss, mse, mean, *rest = values.tolist()
    psnr = -10.0 * math.log10(mse) if mse > 0 else float("inf")
    return {"loss": loss, "psnr": psnr, "loss_mean": mean, **dict(zip(terms, rest))}


def train(backbone: nn.Module, split: Split, losses: LossSet, loop: LoopConfig | Mapping, *,
          optim: OptimConfig | Mapping | None = None, ckpt_dir: str | Path | None = None,
          config: Mapping | None = None, act: nn.Module | None = None, act_lr: float | None = None,
          batch_hook: Callable[[Batch], Batch] | None = None, evaluate: Callable[[int], dict] | None = None,
          on_step: Callable[[int, dict], None] | None = None) -> TrainResult:
    """Train ``backbone`` (and ``act``) on ``split`` for ``loop.steps`` steps.

    Args:
        backbone: a :class:`arcsem.plugins.Backbone`; its ``param_groups(loop.stage)`` are optimised.
        split: training views (images ``[N,H,W,3]``; cameras carry the ACT ``image_ids``).
        losses: the stage's :class:`LossSet`.
        loop: :class:`LoopConfig` or a mapping of its fields.
        optim: :class:`OptimConfig` (``train.optim``) or a mapping.
        ckpt_dir: where ``last.pt`` lives (None: no checkpoints, no resume).
        config: the config that determines the result; stored in checkpoints, compared on resume.
        act: ACT module optimised as group ``"act"`` with rate ``act_lr`` (None in stage 2).
        batch_hook: ``batch -> batch`` run on every batch before rendering (stage 2: ``batch.color``).
        evaluate: ``step -> metrics`` called every ``loop.eval_every`` steps.
        on_step: ``(completed_steps, record)`` after every step (tests, custom logging).
    Returns:
        :class:`TrainResult` (steps, time, loss/PSNR history, periodic evaluations).
    """
    loop = loop if isinstance(loop, LoopConfig) else validate_config(LoopConfig, dict(loop), "train loop")
    optim = optim if isinstance(optim, OptimConfig) else validate_config(OptimConfig, dict(optim or {}), "train.optim")
    run = _Run(backbone, act, split, loop, optim, ckpt_dir, config)
    run.restore(act_lr)
    backbone.train()
    bar = tqdm(total=loop.steps, initial=run.step, desc=loop.desc, disable=not loop.progress, dynamic_ncols=True)
    stop = StopRequest()
    with stop:
        _loop(run, losses, batch_hook, evaluate, on_step, bar, stop)
    if run.resumed_from != loop.steps:  # nothing to add when resuming a finished run
        with torch.random.fork_rng(devices=[]):
            run.save()
    return TrainResult(run.step, run.time_s, run.resumed_from, run.path, run.history, run.evals,
                       run.frozen.summary() if run.frozen is not None else None)


def _loop(run: _Run, losses: LossSet, batch_hook, evaluate, on_step, bar, stop: StopRequest) -> None:
    """The steps; on a stop request (Ctrl-C) write a checkpoint after the step in progress and raise Interrupted."""
    loop = run.loop
    try:
        while run.step < loop.steps:
            t0 = time.perf_counter()
            done = run.step + 1
            logged = done % max(loop.log_every, 1) == 0 or done in (1, loop.steps)
            values = _step(run, losses, batch_hook, run.step, record=logged or on_step is not None)
            if done == loop.steps:
                run.health.read(run)  # the last step's check belongs to the training time
            run.time_s += time.perf_counter() - t0
            run.step = done
            bar.update(1)
            record = None if values is None else {"step": run.step, **values}
            if logged:
                run.history.append(record)
                run.loss_sum, run.loss_n = None, 0
                bar.set_postfix(loss=f"{record['loss']:.4f}", psnr=f"{record['psnr']:.2f}")
            if on_step is not None:
                on_step(run.step, record)
            _periodic(run, evaluate, bar)
            if stop.requested:
                with torch.random.fork_rng(devices=[]):
                    run.save()
                raise Interrupted(f"{loop.desc} interrupted at step {run.step} of {loop.steps}: {run.on_disk()}; "
                                  "run the same command again to resume")
    finally:
        bar.close()


def _periodic(run: _Run, evaluate, bar) -> None:
    loop, s = run.loop, run.step
    evaluating = evaluate is not None and loop.eval_every and s % loop.eval_every == 0 and s < loop.steps
    saving = loop.checkpoint_every and s % loop.checkpoint_every == 0 and s < loop.steps
    if not (evaluating or saving):
        return
    run.health.read(run)
    with torch.random.fork_rng(devices=[]):
        if evaluating:
            run.backbone.eval()
            with torch.no_grad():
                metrics = evaluate(s)
            run.backbone.train()
            run.evals.append({"step": s, **metrics})
            bar.write(f"[{loop.desc}] step {s}: " + ", ".join(f"{k}={v:.4g}" for k, v in metrics.items()
                                                              if isinstance(v, (int, float))))
        if saving:
            run.save()
