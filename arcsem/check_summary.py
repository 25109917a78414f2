"""The one-screen summary ``stage=check`` prints: what was read, built and validated, and what a run
with this config would do. Formatting only: :func:`check_summary` reads the scene, the ``check``
stage's result and the validated configs (a config that fails to validate raises its usual error)."""
from __future__ import annotations

from typing import Any

__all__ = ["check_summary", "run_check_stage"]


def _extras(split) -> str:
    have = [name for name, t in (("masks", split.masks), ("depth", split.depths), ("normals", split.normals),
                                 ("colour", split.colors), ("noise-free grey", split.clean)) if t is not None]
    return ", ".join(have) if have else "none"


def _terms(losses: dict) -> str:
    on = [f"{k} {float((v or {}).get('weight', 1.0)):g}" for k, v in (losses or {}).items()
          if v is not None and float((v or {}).get("weight", 1.0)) != 0]
    return ", ".join(on) or "none"


def _box(bounds) -> str:
    lo, hi = bounds[0].tolist(), bounds[1].tolist()
    return " x ".join(f"[{a:.3g}, {b:.3g}]" for a, b in zip(lo, hi))


def run_check_stage(rc: Any, scene: Any, run_dir: Any) -> dict:
    """``stage=check``: build the backbone and ACT as stage 1 would (validates dataset, plugin and their configs),
    print :func:`check_summary`; trains nothing."""
    from .plugins import BACKBONES
    from .train.stage1 import build_model

    model, act = build_model(rc, scene)
    result = {"backbone_origin": BACKBONES.origin(rc.backbone_name), "primitives": int(model.num_primitives()),
              "act": act is not None}
    print(check_summary(rc, scene, result))
    return result


def check_summary(cfg: Any, scene: Any, result: dict) -> str:
    """Lines (under 80 columns where the data allows) describing a successful ``stage=check``."""
    from .runconfig import run_config

    rc = run_config(cfg)
    cfg, tc, cc, mc = rc.cfg, rc.train, rc.colorize, rc.mesh
    tr, te = scene.train, scene.test
    cams = tr.cameras
    refs = ", ".join(f"{k} ({len(v)})" for k, v in scene.reference_sets.items()) or "none"
    from .preflight import training_size

    w, h = training_size(cams, tc.downscale, tc.width)  # what stage 1 trains at (train.width never upsamples)
    size = f"{w}x{h} px"
    scale, scale_name = scene.scale
    name = str(cfg.backbone.name)
    steps, losses1 = tc.steps, tc.losses  # the preset as tuned for this backbone (conf/tuning)
    stage2 = _stage2_problem(rc, scene)
    lines = [
        "check: OK (the data was read and the model built; nothing was trained)",
        f"  dataset    {cfg.dataset.kind}: {scene.root}",
        f"  views      {len(tr)} train + {len(te)} held-out, {cams.width}x{cams.height} px, {cams.model} cameras",
        f"  per view   ground truth: {_extras(tr)}"
        + (" (grey input: the colour views' luminance, dataset.grey=true)" if cfg.dataset.get("grey") else ""),
        *[f"  intensity  {r['levels']}: {r['views']} view(s)" for r in scene.intensity],
        f"  colour     {len(scene.references)} artist reference image(s); presets: {refs}",
        f"  bounds     {_box(scene.bounds)}",
        f"  errors     relative to the {scale_name}, {scale:.3g} scene units",
        f"  backbone   {name} ({result.get('backbone_origin', '?')}), {result.get('primitives', 0):,} at start",
        f"  ACT        {'on' if result.get('act') else 'off'}",
        f"  stage 1    {steps} steps at {size}; losses: {_terms(losses1)}",
        (f"  stage 2    {cc.steps} steps, references '{cc.references}'{' (cannot run)' if stage2 else ''}; "
         f"losses: {_terms(cc.losses)}"),
        f"  outputs    mesh {'on' if mc.enabled else 'off'}"
        + (f" (voxel {mc.voxel_size:g})" if mc.voxel_size else " (voxel: one training pixel)")
        + f"; videos {'on' if tc.eval.video else 'off'} ({tc.eval.video_frames} frames at {tc.eval.fps} fps)",
        "  run        " + " ".join(["arcsem", *_overrides(cfg), "stage=gray" if stage2 else "stage=all"]),
    ]
    if stage2 is not None:
        lines.append(f"  colour     {stage2}")
    return "\n".join(lines)


def _stage2_problem(rc: Any, scene: Any) -> str | None:
    """None where stage 2 can run as configured, else what to do (the check's warning says what is wrong)."""
    from .colorize.color_stage import check_stage2_inputs
    from .errors import ConfigError, DataError

    try:
        check_stage2_inputs(rc, scene)
    except (ConfigError, DataError) as exc:
        if "reference" in str(exc):
            return "stage 2 needs references: colorize.references=<files/folder named after views>; then stage=all"
        return "stage 2 cannot run as configured (the warning above says why); fix that, then stage=all"
    return None


def _overrides(cfg: Any) -> list[str]:
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return []
    return [o for o in HydraConfig.get().overrides.task if not o.startswith("stage=")]
