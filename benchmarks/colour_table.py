"""The colour comparison's table: held-out colour PSNR (whole, masked, inside and outside the pseudo-colour
coverage) of every stage-2 run folder under a directory, with what validation chose.

    .venv/bin/python benchmarks/colour_table.py DIR [DIR ...]     # run folders DIR/<scene>_<refs>_<variant>/
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def row(run: Path) -> str | None:
    m = json.loads((run / "metrics.json").read_text())
    s2 = m.get("stage2")
    if not s2:
        return f"| {run.name} | failed: {m.get('error')} |"
    t, v = s2["test"], s2.get("validation") or {}
    chose = (f"{v['surface']}/{v['shading']}, TCM {'on' if v.get('tcm', {}).get('keep') else 'off'}, "
             f"CCM {'on' if v.get('ccm', {}).get('keep') else 'off'}") if v else "-"
    return (f"| {run.name} | {t['psnr']:.2f} | {t['psnr_masked']:.2f} | {t['psnr_covered']:.2f} | "
            f"{t['psnr_uncovered']:.2f} | {t['uncovered_px']} | {chose} | {m.get('git_revision', '')[:7]} |")


def main(dirs: list[str]) -> None:
    print("| run | held-out PSNR | masked | inside cov. | outside cov. | px outside | validation chose | commit |")
    print("|---|---:|---:|---:|---:|---:|---|---|")
    for d in dirs:
        for run in sorted(p.parent for p in Path(d).glob("*/metrics.json")):
            print(row(run))


if __name__ == "__main__":
    main(sys.argv[1:])
