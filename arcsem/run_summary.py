"""What a finished run prints last: each stage's result on the views it did not train on, its time, and where
the outputs are (the figures are ``metrics.json``'s; nothing is measured here)."""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["summary_lines"]


def _num(x: Any, spec: str) -> str | None:
    return format(x, spec) if isinstance(x, (int, float)) and math.isfinite(x) else None


def _scores(result: Mapping, colour: bool) -> str:
    """``held-out PSNR 31.23 dB, SSIM 0.949``; the training views' where there is no held-out split."""
    for split, label in (("test", "held-out"), ("train", "training views")):
        part = result.get(split) or {}
        psnr, ssim = _num(part.get("psnr"), ".2f"), _num(part.get("ssim"), ".3f")
        if psnr:
            return f"{label} {'colour ' if colour else ''}PSNR {psnr} dB" + (f", SSIM {ssim}" if ssim else "")
    return "no evaluation"


# a stage's phases (metrics.json timings "<stage>.<phase>_s", arcsem.timing) as the summary names them
PHASES = {"prepare": "set-up", "guidance": "features and validation", "pseudo": "pseudo-colours",
          "matches": "matches", "train": "training", "evaluate": "evaluation", "outputs": "renders and videos",
          "export": "export", "products": "mesh and viewer"}


def _timing(result: Mapping, stage_s: float | None, timings: Mapping | None = None, stage: str = "") -> str:
    """``1500 steps at 14.3 steps/s, 125 s in all (training 108 s, evaluation 11 s, mesh and viewer 5 s)``: the
    phases of a second or more, in the order they ran."""
    steps, sps = result.get("steps"), _num(result.get("steps_per_s"), ".1f")
    out = f"{steps} steps" + (f" at {sps} steps/s" if sps else "") if steps else ""
    total = _num(stage_s, ".0f")
    parts = [f"{PHASES.get(k[len(stage) + 1:-2], k)} {v:.0f} s" for k, v in (timings or {}).items()
             if stage and k.startswith(f"{stage}.") and k.endswith("_s") and _num(v, ".0f") and v >= 1.0]
    total = f"{total} s in all" + (f" ({', '.join(parts)})" if parts else "") if total else None
    return f"{out}, {total}" if out and total else out or (total or "")


def summary_lines(metrics: Mapping, run_dir: str | Path, report: str | Path | None = None) -> list[str]:
    """The closing lines of a run: one per completed stage, then the outputs."""
    lines, timings = [], metrics.get("timings") or {}
    s1, s2 = metrics.get("stage1"), metrics.get("stage2")
    if isinstance(s1, Mapping):
        mesh = ((s1.get("mesh") or {}).get("gt") or {}).get("chamfer_pct")
        extra = f"; mesh Chamfer {mesh:.2f} % of the specimen" if _num(mesh, ".2f") else ""
        lines.append(f"stage 1 ({metrics.get('backbone', '?')}): {_scores(s1, False)}; "
                     f"{_timing(s1, timings.get('gray_s'), timings, 'gray')}{extra}")
    if isinstance(s2, Mapping):
        refs = s2.get("references") or []
        lines.append(f"stage 2 ({len(refs)} reference{'s' if len(refs) != 1 else ''}): {_scores(s2, True)}; "
                     f"{_timing(s2, timings.get('color_s'), timings, 'color')}")
    total = _num(timings.get("total_s"), ".0f")
    lines.append(f"outputs: {Path(run_dir)} (metrics.json{', report/index.html' if report else ''})"
                 + (f"; {total} s in all" if total else ""))
    return lines
