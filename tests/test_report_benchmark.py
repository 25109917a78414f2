"""arcsem-report on `experiment=colorization_benchmark`: the default and pseudo-colours alone compared within each
scene and reference count, paired by seed (fixtures shaped like what ``arcsem`` writes)."""
from __future__ import annotations

import yaml
from report_util import _job, _sweep

from arcsem.report.collect import collect
from arcsem.report.tables import build_table

# (dataset, ablation, seed) -> (held-out PSNR, outside the coverage)
RUNS = {("synthetic", "full", 0): (26.0, 13.0), ("synthetic", "pseudo_only", 0): (24.0, 12.0),
        ("synthetic", "full", 1): (27.0, 14.0), ("synthetic", "pseudo_only", 1): (24.5, 12.5),
        ("diatom", "full", 0): (23.0, 12.0), ("diatom", "pseudo_only", 0): (22.0, 11.0),
        ("diatom", "full", 1): (23.5, 12.0), ("diatom", "pseudo_only", 1): (22.1, 11.2)}


def _benchmark(root):
    sweep = _sweep(root, "colorization_benchmark", "dataset", ["synthetic", "diatom"])
    multirun = yaml.safe_load((sweep / "multirun.yaml").read_text())
    multirun["hydra"]["sweeper"]["params"].update({"colorize.references": "one", "ablation": "full,pseudo_only",
                                                   "seed": "0,1"})
    (sweep / "multirun.yaml").write_text(yaml.safe_dump(multirun))
    for num, ((ds, ablation, seed), (psnr, out)) in enumerate(RUNS.items()):
        test = {"psnr": psnr, "ssim": 0.9, "lpips": None, "psnr_covered": psnr - 3, "psnr_uncovered": out,
                "coverage": 0.8}
        m = {"stage2": {"test": test, "train_nonref": {"psnr": psnr, "ssim": 0.9, "lpips": None}, "references": "one"}}
        _job(sweep, num, ["experiment=colorization_benchmark", f"dataset={ds}", "colorize.references=one",
                          f"ablation={ablation}", f"seed={seed}"], m, seed=seed)
    return sweep


def test_each_scene_and_reference_count_compares_its_own_rows(tmp_path):
    table = build_table(collect([_benchmark(tmp_path / "cb")]), "colorization_benchmark")
    assert table.labels == ["grain, 1, default", "grain, 1, pseudo-colours", "diatom, 1, default",
                            "diatom, 1, pseudo-colours"]
    psnr = [c.key for c in table.columns].index("stage2.test.psnr")
    # bold: the better stage 2 of each scene (the diatom's default is bold though the grain's is higher)
    assert [row[psnr][1] for row in table.cells] == [True, False, True, False]
    whole, outside = (n for n in table.notes if "paired by seed" in n)
    assert whole.startswith("held-out PSNR minus the default of the same scene and reference count")
    # grain: -2.0 and -2.5 (mean -2.25); diatom: -1.0 and -1.4 (mean -1.20); never across scenes
    assert "grain, 1, pseudo-colours -2.25 dB" in whole and "diatom, 1, pseudo-colours -1.20 dB" in whole
    assert "better at 0/2 seeds" in whole and "default" not in whole.split(":", 1)[1]
    assert "grain, 1, pseudo-colours -1.25 dB" in outside and "diatom, 1, pseudo-colours -0.90 dB" in outside
