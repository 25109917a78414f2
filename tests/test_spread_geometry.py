"""benchmarks/spread_geometry.py: the mixed geometries and the depth error in pixel footprints."""
from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import spread_geometry  # (the benchmarks folder is not a package)


def test_mixed_takes_the_references_or_the_rest_from_the_truth():
    model, true = torch.zeros(4, 2, 2), torch.ones(4, 2, 2)
    refs_true = spread_geometry.mixed(model, true, [1, 3], "true")
    refs_model = spread_geometry.mixed(model, true, [1, 3], "model")
    assert refs_true[:, 0, 0].tolist() == [0, 1, 0, 1]
    assert refs_model[:, 0, 0].tolist() == [1, 0, 1, 0]
    assert model.sum() == 0 and true.sum() == 16  # inputs untouched


def test_depth_error_is_in_footprints_over_the_mask():
    true = torch.full((1, 2, 3), 100.0)  # footprint 100 / fx = 1 at fx = 100
    model = true + torch.tensor([[[0.5, 2.0, 20.0], [0.0, 0.0, 50.0]]])
    masks = torch.tensor([[[True, True, True], [True, True, False]]])  # the 50 is outside the mask
    e = spread_geometry.depth_error(model, true, masks, torch.tensor([100.0]))
    assert e["beyond10"] == 0.2  # one of five
    assert abs(e["p50"] - 0.5) < 1e-6
    e2 = spread_geometry.depth_error(model, true, masks, torch.tensor([200.0]))  # footprint 0.5: errors double
    assert abs(e2["p50"] - 1.0) < 1e-6 and e2["beyond10"] == 0.2
