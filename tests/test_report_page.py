"""The report as a reader sees it: rows named by method, no machine paths, the depth colour bar and its
units, links to the runs' files, training curves; and a real run's page in headless Chromium, whose
self-check must pass, and fail when an image goes missing."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from browser import CHROMIUM, SKIP_REASON, Browser
from conftest import write_transforms_scene
from test_config import compose_with

from arcsem import app
from arcsem.report import build_report
from arcsem.report.grids import depth_scale


def _run(folder, backbone="gs2d", act=True, overrides=("experiment=demo",), depth=None):
    folder.mkdir(parents=True)
    stage1 = {"train": {"psnr": 30.0, "ssim": 0.9, "lpips": math.nan}, "test": {"psnr": 29.0, "ssim": 0.88},
              "lpips_weights": "missing: alexnet-owt-7be5be79.pth not in /root/.cache/torch/hub/checkpoints",
              "depth": depth or {}, "mesh": {"gt": {"chamfer_pct": 1.25}}}
    (folder / "metrics.json").write_text(json.dumps({"seed": 0, "backbone": backbone, "overrides": list(overrides),
                                                     "stage1": stage1}))
    (folder / "config.yaml").write_text(yaml.safe_dump({"backbone": {"name": backbone}, "act": {"enabled": act},
                                                        "dataset": {"kind": "synthetic"}}))
    (folder / "train_history.csv").write_text("step,loss,psnr\n10,0.5,12\n20,0.3,15\n30,0.2,18\n")
    (folder / "mesh.ply").write_text("ply\n")
    return folder


def test_rows_named_by_method_without_machine_paths(tmp_path):
    _run(tmp_path / "runs" / "2026-01-01" / "10-00-00")
    _run(tmp_path / "runs" / "2026-01-01" / "11-00-00", backbone="gs3d", act=False, overrides=())
    page = build_report([tmp_path / "runs"], tmp_path / "rep")
    md = (tmp_path / "rep" / "runs.md").read_text()
    assert "| 2DGS + ACT (demo) |" in md and "| 3DGS |" in md
    assert "10-00-00" not in md
    text = page.read_text()
    assert str(tmp_path) not in text and "/root" not in text
    assert "python -m arcsem.weights" in text  # how to get LPIPS
    assert "1.25" in md and "Chamfer %: the TSDF mesh" in md  # the mesh's Chamfer distance: a column, a note
    assert 'href="../runs/2026-01-01/10-00-00/mesh.ply"' in text  # links relative to the page
    assert (tmp_path / "rep" / "curves" / "runs.png").is_file()


def test_depth_colour_bar_and_units(tmp_path):
    run = _run(tmp_path / "r", depth={"display_span": 1.0, "micrometres_per_unit": 12.5})
    assert depth_scale(run) == (12.5, "micrometres")
    (tmp_path / "r2").mkdir()
    assert depth_scale(_run(tmp_path / "r2" / "x", depth={"display_span": 1.0})) == (1.0, "scene units")
    assert depth_scale(_run(tmp_path / "r3")) is None


@pytest.mark.parametrize("model,want", [("ORTHOGRAPHIC", 20.0 * 0.5), (None, 80.0 * 0.5 / 4.0)])
def test_pixel_size_gives_micrometres(tmp_path, model, want):
    from arcsem.data import load_scene

    fl = 20.0 if model else 80.0
    path = write_transforms_scene(tmp_path / "s", n=3, fl=fl, model=model, pixel_size_um=0.5,
                                  aabb=[[-0.5] * 3, [0.5] * 3])
    scene = load_scene({"kind": "transforms", "path": str(path.parent)})
    assert scene.micrometres_per_unit == pytest.approx(want, rel=1e-3)  # cameras ~4 units from the centre


def page_problems(browser) -> list:
    """What the page's own check found, and the same checks made from the test side."""
    found = browser.evaluate("document.body.dataset.check")
    broken = browser.evaluate("Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0)"
                              ".map(i => i.getAttribute('src'))")
    empty = browser.evaluate("Array.from(document.querySelectorAll('table'))"
                             ".filter(t => t.querySelectorAll('td').length === 0).length")
    return ([] if found == "ok" else [f"self-check: {found}"]) + broken + ([f"{empty} empty tables"] if empty else [])


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason=SKIP_REASON)
def test_report_of_a_real_run_in_chromium(tmp_path):
    from PIL import Image

    scene = write_transforms_scene(tmp_path / "scene", n=5, w=32, h=24, fl=60.0, aabb=[[-0.6] * 3, [0.6] * 3])
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "backbone=gs3d", "stage=gray",
                       "train.width=null", "train.steps=30", "train.progress=false", "train.eval.video_frames=6",
                       "train.eval.lpips=false", "mesh.orbit_frames=4", "report=true")
    run = tmp_path / "run"
    app.run(cfg, run_dir=run)
    page = run / "report" / "index.html"
    with Browser(1200, 900) as browser:
        browser.open(page.as_uri(), settle=1.0)
        assert page_problems(browser) == []
        assert browser.evaluate("document.images.length") >= 3  # renders grid, curves, ...
        rows = browser.evaluate("document.querySelectorAll('table td').length")
        png = browser.screenshot(tmp_path / "report.png", full_page=True)
        shot = np.asarray(Image.open(tmp_path / "report.png").convert("L"))
        assert shot.shape[0] > 900 and (shot < 128).mean() > 0.01 and len(png) > 10_000  # text and images drawn
        # a missing image or an emptied table is caught
        next((run / "report" / "grids").glob("*.png")).unlink()
        text = page.read_text()
        page.write_text(text.replace("<td>", "<th>", text.count("<td>")))
        browser.open(page.as_uri(), settle=1.0)
        problems = page_problems(browser)
        assert any(p.startswith("self-check: broken") for p in problems) and any(".png" in p for p in problems)
        assert browser.evaluate("document.getElementById('check').textContent").startswith("This page is incomplete")
        # a table wider than the window (the files table of a stage=all run was, at 1400 px) is caught too
        page.write_text(text.replace('<table class="files">', '<table class="files" style="width:3000px">'))
        browser.open(page.as_uri(), settle=1.0)
        assert "table wider than the window: files" in browser.evaluate("document.getElementById('check').textContent")
    assert rows > 10


def test_weights_command_reports_each_file(tmp_path, monkeypatch, capsys):
    """``python -m arcsem.weights`` (the command the report gives for LPIPS): found / not to be had."""
    import torch

    from arcsem.weights import main

    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    assert main(["alexnet-owt-7be5be79.pth"]) == 1
    assert "alexnet-owt-7be5be79.pth: FAILED:" in capsys.readouterr().out
    (tmp_path / "hub" / "checkpoints").mkdir(parents=True)
    torch.save({"w": torch.zeros(1)}, tmp_path / "hub" / "checkpoints" / "alexnet-owt-7be5be79.pth")
    assert main(["alexnet-owt-7be5be79.pth"]) == 0
    assert "alexnet-owt-7be5be79.pth: ok" in capsys.readouterr().out


@pytest.mark.skipif(CHROMIUM is None, reason=SKIP_REASON)
def test_the_runs_table_of_a_stage_all_run_fits_a_1400_px_window(tmp_path):
    """Every column a stage=all run fills (grey train/held-out, depth, mesh, colour non-ref./held-out, coverage,
    features, validated target) fits a 1400 px window: the page's self-check finds no table wider than it (the
    validated-target column, added for issue 38, first pushed it over)."""
    ims = {"psnr": 31.23, "ssim": 0.949, "lpips": 0.123}
    stage2 = {"train_nonref": ims, "test": {**ims, "psnr_covered": 22.98, "psnr_uncovered": 23.36, "coverage": 0.999},
              "features": "vgg16-random",
              "validation": {"surface": "fill", "shading": "auto", "tcm": {"keep": True}, "ccm": {"keep": True},
                             "target_mse": {"fill/auto": 0.01, "off/off": 0.017}}}
    stage1 = {"train_paper": ims, "test": ims, "depth": {"test_mae_pct": 0.94, "test_mae": 0.0188},
              "mesh": {"gt": {"chamfer_pct": 0.88}}}
    run = tmp_path / "demo"
    run.mkdir()
    (run / "metrics.json").write_text(json.dumps({"seed": 0, "overrides": ["experiment=demo"], "stages": {
        "gray": {"stage1": stage1}, "color": {"stage2": stage2}}}))
    page = build_report([run])
    with Browser(1400, 900) as browser:
        browser.open(page.as_uri(), settle=1.0)
        assert browser.evaluate("document.querySelectorAll('table.metrics th').length") >= 20
        assert page_problems(browser) == []
