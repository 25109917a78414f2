"""arcsem.report.paired: two rows of a study paired by seed, and the note it puts under a table."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from report_util import _job, _stage1, _sweep

from arcsem.report.collect import collect
from arcsem.report.tables import build_table


def test_paired_by_seed_deltas_interval_and_errors(tmp_path):
    """Rows paired by seed: B - A per seed, a t-interval that matches scipy's, wins counted the right
    way for an error metric, an unpaired seed left out, and duplicates / unknown rows refused."""
    from scipy import stats

    from arcsem.errors import DataError
    from arcsem.report.paired import lower_is_better, pair, summary

    sweep = _sweep(tmp_path / "seeds", "grayscale_comparison", "variant", ["gs2d", "gs2d_act"])
    psnr = {"gs2d": [30.0, 31.0, 29.5, 30.2], "gs2d_act": [30.5, 30.8, 30.1]}  # seed 3: no ACT run
    num = 0
    for v, vals in psnr.items():
        for seed, p in enumerate(vals):
            _job(sweep, num, ["experiment=grayscale_comparison", f"variant={v}", f"seed={seed}"],
                 _stage1(33.0 + (v == "gs2d_act") * (0.8 + 0.1 * seed), 0.9, 0.4, p,
                         1.0 + 0.1 * seed * (v == "gs2d_act")), seed)
            num += 1
    df = collect([sweep]).runs
    table, unpaired = pair(df, "gs2d", "gs2d_act", "stage1.test.psnr")
    assert unpaired == [3]
    np.testing.assert_allclose(table["delta"].to_numpy(), [0.5, -0.2, 0.6])
    s = summary(table["delta"], lower_is_better("stage1.test.psnr"))
    lo, hi = stats.t.interval(0.95, 2, loc=np.mean([0.5, -0.2, 0.6]), scale=stats.sem([0.5, -0.2, 0.6]))
    assert (s["n"], s["b_wins"]) == (3, 2)
    assert s["ci_low"] == pytest.approx(lo) and s["ci_high"] == pytest.approx(hi)
    depth, _ = pair(df, "gs2d", "gs2d_act", "stage1.depth.test_mae_pct")
    assert lower_is_better("stage1.depth.test_mae_pct")
    assert summary(depth["delta"], True)["b_wins"] == 0  # ACT's depth error is never lower here
    notes = build_table(collect([sweep]), "grayscale_comparison").notes  # the same pairing, in the table
    note = next(n for n in notes if n.startswith("held-out PSNR minus 2DGS + ACT's, paired by seed"))
    assert "2DGS -0.30 dB" in note
    assert "better at 1/3 seeds" in note
    # both protocols in one table: ACT wins the Table 1 protocol at every seed (training PSNR +0.8, +0.9, +1.0)
    note = next(n for n in notes if n.startswith("PSNR (Table 1 protocol) minus 2DGS + ACT's, paired by seed"))
    assert "2DGS -0.90 dB" in note and "better at 0/3 seeds" in note
    with pytest.raises(DataError, match="no run of row 'gs3d'"):
        pair(df, "gs3d", "gs2d_act", "stage1.test.psnr")
    with pytest.raises(DataError, match="closest columns.*stage1.test.psnr"):
        pair(df, "gs2d", "gs2d_act", "stage1.test.psnrr")
    with pytest.raises(DataError, match="several runs of the same row and seed"):
        pair(collect([sweep, sweep / "0"]).runs.pipe(lambda d: pd.concat([d, d.iloc[:1]])),
             "gs2d", "gs2d_act", "stage1.test.psnr")
