"""The report's colour tables: stage 2's validated target (metrics.json ``stage2.validation``) as a column."""
from __future__ import annotations

import json
from pathlib import Path

from arcsem.report.collect import collect


def test_the_validated_stage2_target_is_a_column_of_the_colour_tables(tmp_path):
    """Stage 2's leave-one-reference-out choice (metrics.json stage2.validation) reaches the report: the target it
    trained towards, its gain over the pseudo-colours alone, and the guided losses kept; 'as configured' without."""
    from arcsem.report.collect import stage2_choice
    from arcsem.report.tables import build_table

    validation = {"references": 5, "surface": "fill", "shading": "auto", "time_s": 2.0,
                  "target_mse": {"fill/auto": 0.01, "fill/off": 0.02, "off/auto": 0.015, "off/off": 0.04},
                  "tcm": {"guidance": 0.002, "target": 0.03, "keep": True},
                  "ccm": {"guidance": 0.09, "target": 0.05, "keep": False}}
    trained = {"five": ["pseudo_color", "reference_l1", "tcm"], "one": ["ccm", "pseudo_color", "reference_l1"]}
    for name, val in (("five", validation), ("one", None)):
        run = tmp_path / "sweep" / name
        run.mkdir(parents=True)
        stage2 = {"test": {"psnr": 27.0, "ssim": 0.9, "lpips": 0.2}, "losses": trained[name],
                  **({"validation": val} if val else {})}
        metrics = {"seed": 0, "overrides": ["experiment=demo"], "stages": {"color": {"stage2": stage2}}}
        (run / "metrics.json").write_text(json.dumps(metrics))
    coll = collect([tmp_path / "sweep"])
    choice = dict(zip(coll.runs["run_dir"].map(lambda p: Path(p).name), coll.runs["stage2_choice"]))
    # the guided losses that trained: at one reference the match check's (no validation), CCM here
    assert choice == {"five": "surface+shading (+6.0 dB) +TCM", "one": "as configured +CCM"}
    table = build_table(coll, "runs")
    col = [c.key for c in table.columns].index("stage2_choice")
    assert sorted(row[col][0] for row in table.cells) == ["as configured +CCM", "surface+shading (+6.0 dB) +TCM"]
    assert any("validated target" in n for n in table.notes)
    off = {"stage2.validation.surface": "off", "stage2.validation.shading": "off",
           "stage2.validation.target_mse.off/off": 0.04}
    assert stage2_choice(off) == "pseudo-colours (+0.0 dB)"
    # a run from before stage2.losses was read: the validation's keep
    assert stage2_choice({**off, "stage2.validation.tcm.keep": True}) == "pseudo-colours (+0.0 dB) +TCM"
    prior = {"stage2.validation.surface": "off", "stage2.validation.shading": "auto", "stage2.validation.prior": "grey",
             "stage2.validation.target_mse.off/auto/grey": 0.01, "stage2.validation.target_mse.off/off/off": 0.1}
    assert stage2_choice(prior) == "shading+prior (+10.0 dB)"  # the grid with the grey prior (issue 38)
    one = {"stage2.validation.references": 1, "stage2.validation.surface": "fill", "stage2.validation.shading": "auto",
           "stage2.validation.prior": "grey", "stage2.validation.target_mse.fill/grey": 0.02,
           "stage2.validation.target_mse.off/off": 0.04}
    assert stage2_choice(one) == "surface+shading+prior (+3.0 dB)"  # one reference: its halves chose
