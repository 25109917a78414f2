"""benchmarks/outside_rim.py: the silhouette's rim and the four parts of the coverage split."""
from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import outside_rim  # (the benchmarks folder is not a package)


def test_rim_is_the_mask_pixels_next_to_its_edge_and_the_image_border():
    m = torch.zeros(1, 9, 12, dtype=torch.bool)
    m[0, 2:7, 3:10] = True  # a 5 x 7 block: its one-pixel edge is the rim at width 1
    rim = outside_rim.rim_masks(m, 1.0)
    inner = torch.zeros_like(m)
    inner[0, 3:6, 4:9] = True
    assert torch.equal(rim, m & ~inner)
    assert int(outside_rim.rim_masks(m, 2.0).sum()) == 35 - 3  # two pixels deep leaves the middle row's 3
    full = torch.ones(1, 5, 5, dtype=torch.bool)  # the image border is the mask's edge too
    assert int(outside_rim.rim_masks(full, 1.0).sum()) == 16


def test_split_parts_partition_the_mask():
    g = torch.Generator().manual_seed(0)
    m, cov, rim = (torch.rand(2, 6, 7, generator=g) > t for t in (0.3, 0.5, 0.6))
    rim &= m
    parts = outside_rim.split_parts(m, cov, rim)
    four = [parts[k] for k in ("rim covered", "rim outside", "inside covered", "inside outside")]
    assert torch.equal(sum(p.int() for p in four), m.int())  # each mask pixel in exactly one part
    assert torch.equal(parts["outside"], parts["rim outside"] | parts["inside outside"])
    assert torch.equal(parts["outside"], m & ~cov)
