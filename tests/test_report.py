"""arcsem.report: tables (CSV/Markdown/LaTeX), missing jobs and the HTML page, on fake run folders (its grids, curves
and posters: test_report_grids.py).

The run folders built here are fixtures shaped like what ``arcsem`` writes (metrics.json,
config.yaml, .hydra/overrides.yaml, multirun.yaml, renders/, colored/), not mocks of the product.
"""
from __future__ import annotations

import json
import math
from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest
import yaml
from report_util import GRAY, _job, _png, _stage1, _sweep

from arcsem.report import build_report
from arcsem.report.collect import collect, expected_jobs, parse_overrides
from arcsem.report.formats import to_latex, to_markdown, write_tables
from arcsem.report.tables import LAYOUTS, build_table


@pytest.fixture
def gray_sweep(tmp_path: Path) -> Path:
    """grayscale_comparison: 4 jobs, job 3 (gs2d_act) interrupted (folder, no metrics)."""
    sweep = _sweep(tmp_path / "gray", "grayscale_comparison", "variant", list(GRAY))
    for i, v in enumerate(GRAY):
        done = v != "gs2d_act"
        job = _job(sweep, i, ["experiment=grayscale_comparison", f"variant={v}"],
                   _stage1(*GRAY[v]) if done else None)
        if done:
            _png(job / "renders/test/r_000.png", 40 * i)
            _png(job / "renders/test/r_000_depth.png", 40 * i + 10)
            (job / "videos").mkdir()
            (job / "videos" / "turntable.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    _png(sweep / "0/renders/test/r_000_gt.png", 255)
    return sweep


@pytest.fixture
def ref_sweep(tmp_path: Path) -> Path:
    """reference_count with two seeds for 'five', NaN LPIPS everywhere, 'one' never started."""
    sweep = _sweep(tmp_path / "refs", "reference_count", "colorize.references", ["five", "two", "one"])
    psnr = {"five": [26.0, 27.0], "two": [24.0]}
    num = 0
    for refs, vals in psnr.items():
        for seed, p in enumerate(vals):
            m = {"stage2": {"train_nonref": {"psnr": p, "ssim": 0.9, "lpips": None},
                            "test": {"psnr": p - 1, "ssim": 0.85, "lpips": math.nan},
                            "features": "random", "references": refs,
                            "lpips_weights": "missing: alexnet-owt-7be5be79.pth not in torch hub cache"}}
            job = _job(sweep, num, ["experiment=reference_count", f"colorize.references={refs}",
                                    f"seed={seed}"], m, seed)
            _png(job / "colored/r_001.png", 100 + num)
            num += 1
    # the multirun sweeps two seeds for 'five' only through separate jobs; declare what was expected
    multirun = yaml.safe_load((sweep / "multirun.yaml").read_text())
    multirun["hydra"]["sweeper"]["params"] = {"colorize.references": "five,two,one", "seed": "0,1"}
    (sweep / "multirun.yaml").write_text(yaml.safe_dump(multirun))
    return sweep


def test_parse_and_expand_overrides(ref_sweep):
    assert parse_overrides(["+variant=gs2d", "~foo=1", "a.b=x=y"]) == {"variant": "gs2d", "foo": "1", "a.b": "x=y"}
    jobs = expected_jobs(ref_sweep / "multirun.yaml")
    assert len(jobs) == 6  # 3 reference sets x 2 seeds
    assert ["colorize.references=one", "seed=1", "experiment=reference_count"] in jobs


def test_collect_flattens_and_lists_missing(gray_sweep):
    coll = collect([gray_sweep])
    df = coll.runs
    assert sorted(df["row"]) == ["gs2d", "gs3d", "plenoxels"]
    assert set(df["study"]) == {"grayscale_comparison"}
    row = df[df["row"] == "gs3d"].iloc[0]
    assert row["stage1.train_paper.psnr"] == 33.5 and row["stage1.train.psnr"] == 83.5 and row["stage1.depth.test_mae_pct"] == 1.5
    assert row["git"] == "abc123" and row["variant"] == "gs3d"
    assert len(coll.missing) == 1
    miss = coll.missing[0]
    assert miss.row == "gs2d_act" and miss.job_dir.endswith("/3") and "variant=gs2d_act" in miss.overrides


def test_grayscale_table_bold_paper_and_missing(gray_sweep, tmp_path):
    t = build_table(collect([gray_sweep]), "grayscale_comparison")
    assert t.labels == ["Plenoxels", "3DGS", "2DGS", "2DGS + ACT"]
    md = to_markdown(t)
    lines = {ln.split("|")[1].strip(): ln for ln in md.splitlines() if ln.startswith("| ")}
    # best train PSNR 33.50 (3DGS) and SSIM 0.900 bold; best LPIPS 0.400 (min) bold; depth best 0.80 (2DGS)
    assert "**33.50**" in lines["3DGS"] and "**0.900**" in lines["3DGS"] and "**0.400**" in lines["3DGS"]
    assert "**0.80**" in lines["2DGS"] and "30.00" in lines["Plenoxels"] and "**30.00**" not in md
    assert "99.00" not in md and "**0.0080**" in lines["2DGS"]
    # the paper's Table 1 beside ours, its best (3DGS 37.50) in bold; the missing row says so
    assert "**37.50**" in lines["3DGS"] and "36.32" in lines["2DGS + ACT"]
    assert lines["2DGS + ACT"].count("missing") == 8  # 3 train + 3 held-out + 2 depth; paper cells kept
    assert any("missing job: experiment=grayscale_comparison variant=gs2d_act" in n for n in t.notes)
    assert "LPIPS: AlexNet v0.1, ImageNet weights alexnet-owt-7be5be79.pth." in t.notes
    assert any(n.startswith("metrics (3dgs): the 3DGS/2DGS evaluation scripts' convention") for n in t.notes)
    assert not any("n/a" in n for n in t.notes)
    tex = to_latex(t)
    assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    assert r"\textbf{33.50}" in tex and r"\textbf{0.400}" in tex and r"\textbf{30.00}" not in tex
    assert r"\multicolumn{3}{c}{train views: own ACT, observed images (Table 1 protocol)}" in tex and r"2DGS + ACT & missing" in tex
    assert "grayscale\\_comparison" in tex  # escaped underscore in the caption


def test_nan_lpips_na_mean_std_and_features(ref_sweep, tmp_path):
    out = tmp_path / "out"
    tables = write_tables(collect([ref_sweep]), out)
    t = tables["reference_count"]
    md = (out / "reference_count.md").read_text()
    lines = {ln.split("|")[1].strip(): ln for ln in md.splitlines() if ln.startswith("| ")}
    assert t.labels == ["5", "2", "1"]
    # two seeds of 'five': mean 26.50, sample std 0.71; best mean in bold
    assert "**26.50 ± 0.71**" in lines["5"] and "24.00" in lines["2"]
    cells = [c.strip() for c in lines["5"].split("|")[2:-1]]
    assert cells[2] == "n/a" and cells[5] == "n/a"  # LPIPS train / held-out
    assert lines["1"].count("missing") == 8  # six metrics, the features and the validated-target columns
    assert "LPIPS: n/a: weights missing (missing: alexnet-owt-7be5be79.pth not in torch hub cache)" in md
    assert "TCM/CCM features: random." in md and "RANDOM weights in every run that uses them" in md
    assert cells[-2:] == ["random", "as configured"]  # the features and validated-target columns
    assert md.count("missing job:") == 3  # five/seed=1 is done; two/seed=1, one/seed=0, one/seed=1 are not
    csv = pd.read_csv(out / "reference_count.csv")
    five = csv[csv["row"] == "five"].iloc[0]
    assert five["n"] == 2 and abs(five["stage2.train_nonref.psnr"] - 26.5) < 1e-12
    assert abs(five["stage2.train_nonref.psnr.std"] - math.sqrt(0.5)) < 1e-12
    assert math.isnan(five["stage2.test.lpips"])
    assert csv[csv["row"] == "one"].iloc[0]["status"] == "missing"
    assert (out / "all_runs.csv").is_file() and (out / "reference_count.tex").is_file()


class _Refs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs, self.tags = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        for name, value in attrs:
            if (tag, name) in {("img", "src"), ("video", "src"), ("a", "href"), ("source", "src")}:
                self.refs.append(value)


def test_html_page_links_exist_and_grids(gray_sweep, ref_sweep, tmp_path):
    out = tmp_path / "report"
    (out / "grids").mkdir(parents=True)
    (out / "grids" / "reference_count_color_3.png").write_bytes(b"an earlier report's grid")
    page = build_report([gray_sweep, ref_sweep], out)
    assert not (out / "grids" / "reference_count_color_3.png").exists()  # not left beside this report's
    parser = _Refs()
    parser.feed(page.read_text())
    parser.close()
    assert parser.tags.count("table") == 4 and parser.tags.count("video") == 3  # 2 studies + their files tables
    files = [r for r in parser.refs if not r.startswith("#")]
    assert any(r.endswith(".png") for r in files) and any(r.endswith(".mp4") for r in files)
    for ref in files:
        assert not ref.startswith(("/", "http")), ref
        assert (out / ref).is_file(), ref
    # grid: 1 view row, columns GT + 4 rows of the table (gs2d_act has no run -> not a column)
    import cv2

    grid = cv2.imread(str(out / "grids" / "grayscale_comparison_gray.png"))
    assert grid.shape[0] == 160 + 22
    tile_w = round(160 * 16 / 12)
    assert grid.shape[1] == 90 + 4 * tile_w
    # ground truth tile (white, 255) then the plenoxels render (value 0)
    assert grid[22 + 80, 90 + tile_w // 2, 0] == 255 and grid[22 + 80, 90 + tile_w + tile_w // 2, 0] == 0
    color = cv2.imread(str(out / "grids" / "reference_count_color.png"))
    # no ground-truth colour in these runs: the first tile is the grey 'missing' placeholder
    assert color[22 + 5, 90 + 5, 0] == 200


def test_cli_default_out_and_error(gray_sweep, tmp_path, capsys):
    from arcsem.cli.report import main

    assert main([str(gray_sweep)]) == 0
    assert (gray_sweep / "report" / "index.html").is_file()
    assert (gray_sweep / "report" / "grayscale_comparison.md").is_file()
    # a second report does not pick up its own output folder
    (gray_sweep / "report" / "stale.mp4").write_bytes(b"x")
    assert main([str(gray_sweep)]) == 0
    assert len(pd.read_csv(gray_sweep / "report" / "all_runs.csv")) == 3
    assert not list((gray_sweep / "report" / "videos").rglob("*stale*"))
    assert main([str(tmp_path / "nope")]) == 2
    assert "no such run or multirun folder" in capsys.readouterr().err


def test_single_run_in_app_layout(tmp_path):
    """A plain run (no sweep) whose stage results are only under ``stages.gray``; report inside it."""
    run = tmp_path / "outputs" / "run1"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(yaml.safe_dump({"seed": 3, "dataset": {"path": str(tmp_path / "ds")}}))
    metrics = {"seed": 3, "git_revision": "f00", "overrides": ["experiment=grayscale_comparison", "+variant=gs3d"],
               "stages": {"gray": {"train_paper": {"psnr": 31.0, "ssim": 0.8, "lpips": 0.3}}}}
    (run / "metrics.json").write_text(json.dumps(metrics))
    _png(run / "renders/test/v1.png", 50)
    _png(tmp_path / "ds" / "test" / "v1.png", 250)  # ground truth found in the dataset folder
    (run / "turntable.mp4").write_bytes(b"mp4")
    coll = collect([run])
    rec = coll.runs.iloc[0]
    assert (rec["study"], rec["row"], rec["git"], rec["seed"]) == ("grayscale_comparison", "gs3d", "f00", 3)
    assert rec["stage1.train_paper.psnr"] == 31.0 and coll.missing == []
    page = build_report([run])
    assert page == run / "report" / "index.html"
    build_report([run])  # again: the report's own video copy is not collected a second time
    assert [p.name for p in (run / "report" / "videos").rglob("*.mp4")] == ["3DGS_turntable.mp4"]
    import cv2

    grid = cv2.imread(str(run / "report" / "grids" / "grayscale_comparison_gray.png"))
    assert grid[22 + 80, 95, 0] == 250 and grid[22 + 80, grid.shape[1] - 5, 0] == 50
    md = (run / "report" / "grayscale_comparison.md").read_text()
    assert "| 3DGS | 31.00 | 0.800 | 0.300 | 37.50 |" in md  # one row: nothing to be best against


def test_lpips_note_ignores_missing_rows(gray_sweep):
    """Only rows that ran decide the LPIPS note: the missing 2DGS + ACT row does not make it 'n/a'."""
    for job in ("0", "1", "2"):
        m = json.loads((gray_sweep / job / "metrics.json").read_text())
        del m["stage1"]["lpips_weights"]
        (gray_sweep / job / "metrics.json").write_text(json.dumps(m))
    notes = build_table(collect([gray_sweep]), "grayscale_comparison").notes
    assert "LPIPS weights: not recorded." in notes and not any("n/a" in n for n in notes)


def test_runs_of_no_study_get_a_table_and_grids(tmp_path):
    """A demo run (experiment=demo, stage all) is reported as a row of the generic 'runs' table."""
    run = tmp_path / "outputs" / "2026-01-01" / "12-00-00"
    s1 = _stage1(33.0, 0.9, math.nan, 31.0, 0.5, "missing: no alexnet weights")
    s2 = {"stage2": {"train_nonref": {"psnr": 27.0, "ssim": 0.9, "lpips": math.nan},
                     "test": {"psnr": 26.0, "ssim": 0.88, "lpips": math.nan}, "features": "imagenet"}}
    _job(run.parent, 0, ["experiment=demo"], {**s1, **s2})
    (run.parent / "0").rename(run)
    _png(run / "renders/test/t0.png", 30)
    _png(run / "colored/v0.png", 90)
    _png(run / "colored/v0_gt.png", 91)
    page = build_report([tmp_path / "outputs"], tmp_path / "rep")
    md = (tmp_path / "rep" / "runs.md").read_text()
    assert "| 2026-01-01/12-00-00 | 33.00 | 0.900 | n/a | 31.00 |" in md
    assert "LPIPS: n/a: weights missing (missing: no alexnet weights)" in md
    assert "TCM/CCM features: imagenet." in md and md.splitlines()[4].endswith("| imagenet | as configured |")
    grids = sorted(p.name for p in (tmp_path / "rep" / "grids").iterdir())
    assert grids == ["runs_color.png", "runs_gray.png"]  # no depth files -> no depth grid
    assert 'src="grids/runs_color.png"' in page.read_text()


FIX = (" To get LPIPS, fetch the ImageNet weights on a machine with network (python -m arcsem.weights) and run the "
       "job again: a number made with random weights is never shown.")


@pytest.mark.parametrize("values, nan, expected", [
    (["/hub/checkpoints/alexnet-owt-7be5be79.pth"], False, ["LPIPS: AlexNet v0.1, ImageNet weights alexnet-owt-7be5be79.pth."]),
    (["missing: no file; skipped"], True, ["LPIPS: n/a: weights missing (missing: no file; skipped)." + FIX]),
    ([], True, ["LPIPS: n/a: weights missing (not recorded)." + FIX]),
    ([], False, ["LPIPS weights: not recorded."]),
    (["a/alexnet.pth", "missing: offline"], True,
     ["LPIPS: n/a: weights missing (missing: offline)." + FIX, "LPIPS: AlexNet v0.1, ImageNet weights alexnet.pth."]),
    (["/hub/checkpoints/vgg16-397923af.pth"], False, ["LPIPS: VGG16 v0.1, ImageNet weights vgg16-397923af.pth."]),
    (["missing: alexnet-owt-7be5be79.pth not in /root/.cache/torch/hub/checkpoints and no network"], True,
     ["LPIPS: n/a: weights missing (missing: alexnet-owt-7be5be79.pth not in the torch hub cache and no network)."
      + FIX]),
])
def test_lpips_notes(values, nan, expected):
    from arcsem.report.tables import _lpips_notes

    assert _lpips_notes(values, nan) == expected


def test_sweep_with_no_finished_job(tmp_path):
    """Every job failed: the table still has the study's columns, each cell 'missing'."""
    sweep = _sweep(tmp_path / "s", "colorization_ablation", "ablation", ["full", "no_tcm"])
    _job(sweep, 0, ["experiment=colorization_ablation", "ablation=full"], None)
    t = build_table(collect([sweep]), "colorization_ablation")
    assert t.labels == ["full", "w/o TCM"] and len(t.columns) == len(LAYOUTS["colorization_ablation"]) == 11
    assert all(cell == ("missing", False) for row in t.cells for cell in row)
    assert sum(n.startswith("missing job:") for n in t.notes) == 2 and not any("LPIPS" in n for n in t.notes)


def test_broken_metrics_json_is_missing_not_fatal(gray_sweep):
    (gray_sweep / "1" / "metrics.json").write_text('{"seed": 0, "stage1": {"tr')  # truncated
    coll = collect([gray_sweep])
    assert sorted(coll.runs["row"]) == ["gs2d", "plenoxels"]
    broken = next(m for m in coll.missing if m.row == "gs3d")
    assert broken.job_dir.endswith("/1") and "metrics.json: not valid JSON" in broken.reason
    md = to_markdown(build_table(coll, "grayscale_comparison"))
    assert "| 3DGS | missing |" in md and "not valid JSON" in md
