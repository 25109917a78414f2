"""arcsem.report: tables (CSV/Markdown/LaTeX), missing jobs, grids and the HTML page, on fake run folders.

The run folders built here are fixtures shaped like what ``arcsem`` writes (metrics.json,
config.yaml, .hydra/overrides.yaml, multirun.yaml, renders/, colored/), not mocks of the product.
"""
from __future__ import annotations

import json
import math
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
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


def test_ground_truth_rendered_from_the_runs_dataset(tmp_path, tiny_transforms):
    """No GT file in the run: the grid's GT tile is the dataset's image, read back via load_scene."""
    import cv2

    scene_json = tiny_transforms(n=4)
    run = tmp_path / "runs" / "r"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(yaml.safe_dump({"seed": 0, "dataset": {"kind": "transforms",
                                                                             "path": str(scene_json)}}))
    (run / "metrics.json").write_text(json.dumps({"seed": 0, "overrides": [], "stage1": {"train": {"psnr": 20.0}}}))
    _png(run / "renders/test/view_01.png", 10)
    build_report([tmp_path / "runs"], tmp_path / "rep")
    tile = cv2.imread(str(tmp_path / "rep" / "grids" / "gt" / "gray_view_01.png"))
    src = cv2.imread(str(scene_json.parent / "view_01.png"), cv2.IMREAD_GRAYSCALE)
    assert tile is not None and np.abs(tile[..., 0].astype(int) - src).max() <= 1
    assert not (tmp_path / "rep" / "grids" / "gt" / "depth_view_01.png").exists()  # no GT depth in this dataset


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


def test_grid_falls_back_to_training_view_renders(tmp_path):
    """A dataset without held-out views: the grids show renders/train/ (and say so)."""
    from arcsem.report.grids import study_grids

    run = tmp_path / "r"
    _png(run / "renders/train/a.png", 70)
    _png(run / "renders/train/a_depth.png", 80)
    grids = study_grids("grayscale_comparison", {"3DGS": run}, tmp_path / "g")
    assert [t for t, _ in grids] == ["grayscale_comparison: renders (training views)",
                                     "grayscale_comparison: depth maps (training views)"]
    import cv2

    img = cv2.imread(str(grids[1][1]))
    assert img[22 + 80, img.shape[1] - 5, 0] == 80 and img[22 + 80, 95, 0] == 200  # render; GT 'missing'


def test_broken_metrics_json_is_missing_not_fatal(gray_sweep):
    (gray_sweep / "1" / "metrics.json").write_text('{"seed": 0, "stage1": {"tr')  # truncated
    coll = collect([gray_sweep])
    assert sorted(coll.runs["row"]) == ["gs2d", "plenoxels"]
    broken = next(m for m in coll.missing if m.row == "gs3d")
    assert broken.job_dir.endswith("/1") and "metrics.json: not valid JSON" in broken.reason
    md = to_markdown(build_table(coll, "grayscale_comparison"))
    assert "| 3DGS | missing |" in md and "not valid JSON" in md


def test_grid_reads_renders_of_a_shared_stage1_model(tmp_path):
    """share_stage1: the run's stage-1 renders live behind its stage1/ link to the shared model."""
    from arcsem.report.grids import study_grids

    shared, run = tmp_path / "cache" / "abc", tmp_path / "r"
    _png(shared / "renders/test/a.png", 70)
    _png(shared / "renders/test/a_depth.png", 80)
    (shared / "turntable.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    run.mkdir()
    (run / "stage1").symlink_to(shared, target_is_directory=True)
    grids = study_grids("grayscale_comparison", {"2DGS": run}, tmp_path / "g")
    assert [t for t, _ in grids] == ["grayscale_comparison: renders (held-out views)",
                                     "grayscale_comparison: depth maps (held-out views)"]
    from arcsem.report.html import copy_videos

    videos = copy_videos("grayscale_comparison", {"2DGS": run}, tmp_path / "out")
    assert [c for c, _ in videos] == ["2DGS: turntable"] and videos[0][1].is_file()



def test_report_videos_get_a_poster_of_their_middle_frame(tmp_path):
    """A browser shows a black box for a <video> it has not loaded: each copied video gets its middle frame
    as poster."""
    import cv2
    import numpy as np

    from arcsem.report.html import _section, copy_videos
    from arcsem.report.tables import Table
    from arcsem.video import write_video

    run = tmp_path / "r"
    run.mkdir()
    frames = [np.full((64, 96, 3), 20 * i, np.uint8) for i in range(9)]   # frame i has grey level 20 i
    write_video(run / "turntable.mp4", frames, fps=5)
    videos = copy_videos("grayscale_comparison", {"2DGS": run}, tmp_path / "out")
    poster = videos[0][1].with_suffix(".jpg")
    assert poster.is_file() and abs(float(cv2.imread(str(poster)).mean()) - 80) < 6      # frame 4 of 9
    page = _section(Table("grayscale_comparison", [], [], [], None, []), [], videos, tmp_path / "out")
    assert 'poster="videos/grayscale_comparison/2DGS_turntable.jpg"' in page


def test_colour_grid_shows_held_out_views_and_marks_references(tmp_path):
    """The colour grid takes stage 2's held-out renders (colorize/renders/test/, title says so) where a run has
    them; from training views it marks the references (metrics.json stage2.references) beside their names."""
    import cv2

    from arcsem.report.grids import study_grids

    run = tmp_path / "r"
    _png(run / "colored/v0.png", 90)
    _png(run / "colored/v1.png", 95)
    (run / "metrics.json").write_text('{"stage2": {"references": ["v1"]}}')
    training = study_grids("reference_count", {"five": run}, tmp_path / "g1")
    assert [t for t, _ in training] == ["reference_count: coloured views"]
    marked = cv2.imread(str(training[0][1]))
    _png(run / "colorize/renders/test/t0.png", 60)
    _png(run / "colorize/renders/test/t0_gt.png", 61)
    held = study_grids("reference_count", {"five": run}, tmp_path / "g2")
    assert [t for t, _ in held] == ["reference_count: coloured views (held-out views)"]
    img = cv2.imread(str(held[0][1]))
    assert img[22 + 80, img.shape[1] - 5, 0] == 60 and img[22 + 80, 95, 0] == 61  # render; its true colour
    tile_h = marked.shape[0] // 2  # v0, v1: the reference's row label has a second line, "(reference)"
    row_label = lambda r: int((marked[r * tile_h: (r + 1) * tile_h, :90] < 128).any(-1).any(-1).sum())
    assert row_label(1) > 1.5 * row_label(0)


def test_runs_on_several_datasets_get_a_grid_each_with_their_own_views(tmp_path):
    """colorization_benchmark's scenes have views of their own names: one grid per dataset (config.yaml), each with
    its views and ground truth, its labels without the scene they share; no tile is "missing"."""
    import cv2

    from arcsem.report.grids import study_grids

    runs = {}
    for scene, views, level in (("grain", ["h_01", "v_09"], 60), ("chair", ["r_0", "r_88"], 120)):
        for variant in ("default", "pseudo-colours"):
            run = tmp_path / f"{scene}_{variant}"
            (run / "config.yaml").parent.mkdir(parents=True)
            (run / "config.yaml").write_text(f"dataset:\n  kind: transforms\n  path: /data/{scene}\n")
            for v in views:
                _png(run / f"colorize/renders/test/{v}.png", level)
                _png(run / f"colorize/renders/test/{v}_gt.png", level + 1)
            runs[f"{scene}, 1, {variant}"] = run
    grids = study_grids("colorization_benchmark", runs, tmp_path / "g")
    assert [t for t, _ in grids] == ["colorization_benchmark: coloured views (held-out views), grain",
                                     "colorization_benchmark: coloured views (held-out views), chair"]
    for (_, path), level in zip(grids, (60, 120)):
        img = cv2.imread(str(path))
        tiles = img[22:22 + 160 - 1, 90:, 0]  # the first view's row: the ground truth, then the two runs
        assert set(np.unique(tiles[80])) <= {level, level + 1, 255}  # no grey "missing" tile (200, its border 120)
    one = study_grids("colorization_benchmark", dict(list(runs.items())[:2]), tmp_path / "g1")
    assert [t for t, _ in one] == ["colorization_benchmark: coloured views (held-out views)"]  # one dataset: as before


def test_rows_sharing_a_stage1_model_draw_one_curve(tmp_path):
    """share_stage1: the default and pseudo-colour rows of one scene and seed link one stage-1 folder; the training
    curves draw it once, named by the first row and how many more share it; a model of its own stays its own."""
    from arcsem.report.curves import histories, training_curves

    shared = tmp_path / "cache" / "stage1" / "abc"
    shared.mkdir(parents=True)
    (shared / "train_history.csv").write_text("step,loss,psnr\n1,0.5,10\n2,0.4,12\n")
    runs = {}
    for label in ("grain, 1, default", "grain, 1, pseudo-colours", "grain, 3, default"):
        run = tmp_path / label.replace(", ", "_")
        run.mkdir()
        (run / "stage1").symlink_to(shared)
        runs[label] = run
    own = tmp_path / "own"
    own.mkdir()
    (own / "train_history.csv").write_text("step,loss,psnr\n1,0.6,9\n2,0.3,14\n")
    runs["diatom, 1, default"] = own
    got = histories(runs)
    assert list(got) == ["grain, 1, default (+2 rows)", "diatom, 1, default"]
    assert got["diatom, 1, default"]["psnr"].tolist() == [9, 14]
    assert training_curves(runs, tmp_path / "c.png").is_file()
