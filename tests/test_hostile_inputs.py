"""The hostile-input table (benchmarks/hostile_inputs.py) in CI: every case gets the answer it must get (a clear
error naming the file or key, a warning, or a run), no input changes, nothing is written outside the run folder, and
metrics.json is strict JSON. Each case runs in-process as the console script would (about a second each)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import hostile_inputs  # the benchmarks folder is not a package

pytestmark = pytest.mark.slow

CASES = {c.name: c for c in hostile_inputs.all_cases()}


def test_case_names_are_unique_and_the_table_grew():
    assert len(CASES) == len(hostile_inputs.all_cases())
    assert len(hostile_inputs.CASES) >= 60  # issue 40's classes and around them
    tiff = [c for c in hostile_inputs.CASES if "TIFF" in c.name or c.tool == "calibrate"]
    assert len(tiff) >= 60 and sum(c.tool == "calibrate" for c in tiff) >= 20  # real SEM files first


@pytest.mark.parametrize("name", sorted(CASES))
def test_hostile_input_is_answered(tmp_path, name):
    row = hostile_inputs.run_case(tmp_path, CASES[name])
    assert row["verdict"] == "pass", row
    assert not row["inputs_changed"] and not row["written_outside"], row
    assert row["strict_metrics_json"], row
