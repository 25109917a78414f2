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


def _timing(result: Mapping, stage_s: float | None) -> str:
    steps, sps = result.get("steps"), _num(result.get("steps_per_s"), ".1f")
    out = f"{steps} steps" + (f" at {sps} steps/s" if sps else "") if steps else ""
    total = _num(stage_s, ".0f")
    return f"{out}, {total} s in all" if out and total else out or (f"{total} s" if total else "")


def summary_lines(metrics: Mapping, run_dir: str | Path, report: str | Path | None = None) -> list[str]:
    """The closing lines of a run: one per completed stage, then the outputs."""
    lines, timings = [], metrics.get("timings") or {}
    s1, s2 = metrics.get("stage1"), metrics.get("stage2")
    if isinstance(s1, Mapping):
        mesh = ((s1.get("mesh") or {}).get("gt") or {}).get("chamfer_pct")
        extra = f"; mesh Chamfer {mesh:.2f} % of the specimen" if _num(mesh, ".2f") else ""
        lines.append(f"stage 1 ({metrics.get('backbone', '?')}): {_scores(s1, False)}; "
                     f"{_timing(s1, timings.get('gray_s'))}{extra}")
    if isinstance(s2, Mapping):
        refs = s2.get("references") or []
        lines.append(f"stage 2 ({len(refs)} reference{'s' if len(refs) != 1 else ''}): {_scores(s2, True)}; "
                     f"{_timing(s2, timings.get('color_s'))}")
    total = _num(timings.get("total_s"), ".0f")
    lines.append(f"outputs: {Path(run_dir)} (metrics.json{', report/index.html' if report else ''})"
                 + (f"; {total} s in all" if total else ""))
    return lines
