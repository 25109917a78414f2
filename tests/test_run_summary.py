"""A run ends with what it achieved: each stage's held-out scores and time, and where its outputs are."""
from __future__ import annotations

import math

from arcsem.run_summary import summary_lines

METRICS = {
    "backbone": "gs2d", "timings": {"gray_s": 227.2, "color_s": 115.3, "total_s": 343.8},
    "stage1": {"test": {"psnr": 31.2316, "ssim": 0.94857}, "steps": 1500, "steps_per_s": 8.01,
               "mesh": {"gt": {"chamfer_pct": 0.8839}}},
    "stage2": {"test": {"psnr": 27.9275, "ssim": 0.9214}, "steps": 600, "steps_per_s": 7.5,
               "references": ["h_00", "h_10", "h_19", "v_06", "v_11"]},
}


def test_both_stages_outputs_and_report():
    lines = summary_lines(METRICS, "/runs/demo", "/runs/demo/report/index.html")
    assert lines == [
        ("stage 1 (gs2d): held-out PSNR 31.23 dB, SSIM 0.949; 1500 steps at 8.0 steps/s, 227 s in all; "
         "mesh Chamfer 0.88 % of the specimen"),
        "stage 2 (5 references): held-out colour PSNR 27.93 dB, SSIM 0.921; 600 steps at 7.5 steps/s, 115 s in all",
        "outputs: /runs/demo (metrics.json, report/index.html); 344 s in all",
    ]


def test_stage_one_alone_without_a_held_out_split_and_missing_figures():
    m = {"backbone": "plenoxels", "timings": {},
         "stage1": {"test": {"psnr": math.nan}, "train": {"psnr": 25.5}, "steps": 10}}
    assert summary_lines(m, "out") == ["stage 1 (plenoxels): training views PSNR 25.50 dB; 10 steps",
                                       "outputs: out (metrics.json)"]


def test_each_stage_says_where_its_time_went():
    """The phases ``metrics.json`` times (a second or more, in the order they ran) follow each stage's total."""
    timings = {**METRICS["timings"], "gray.prepare_s": 0.05, "gray.train_s": 108.04, "gray.evaluate_s": 11.3,
               "gray.export_s": 0.03, "gray.products_s": 5.13, "color.guidance_s": 4.5, "color.train_s": 13.6,
               "color.outputs_s": 9.23}
    lines = summary_lines({**METRICS, "timings": timings}, "/runs/demo")
    assert lines[0].endswith("227 s in all (training 108 s, evaluation 11 s, mesh and viewer 5 s); "
                             "mesh Chamfer 0.88 % of the specimen"), lines[0]
    assert lines[1].endswith("115 s in all (features and validation 4 s, training 14 s, renders and videos 9 s)"), \
        lines[1]
