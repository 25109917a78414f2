"""The example plugin examples/mip_splatting (installed by `make test`): its 3-D filter, its place in a study.

The contract tests (tests/test_backbone_contract.py) run on it too, as on every installed backbone.
"""
from __future__ import annotations

import pytest
import torch

from arcsem.cameras import Cameras, look_at

mip = pytest.importorskip("arcsem_mip.filter3d", reason="examples/mip_splatting is installed by `make test`")


def cams(model: str) -> Cameras:
    eye = torch.tensor([[0.0, 0.0, -4.0], [0.0, 0.0, -2.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]], dtype=torch.float64).repeat(2, 1, 1)
    return Cameras(w2c, K, 100, 100, model)


def test_filter_variance_is_the_finest_sampling_that_saw_each_centre():
    means = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, -0.5], [50.0, 0.0, 0.0]], dtype=torch.float64)
    v = mip.filter_variance(means, cams("pinhole"), s=0.2)
    # pinhole: the nearer camera (distance 2, and 1.5 for the second centre) samples f / z px per unit
    assert v[0].item() == pytest.approx(0.2 / (100 / 2.0) ** 2)
    assert v[1].item() == pytest.approx(0.2 / (100 / 1.5) ** 2)
    assert v[2].item() == pytest.approx(v[0].item())  # seen by no camera: the largest of the others
    ortho = mip.filter_variance(means[:2], cams("orthographic"), s=0.2)
    torch.testing.assert_close(ortho, torch.full((2,), 0.2 / 100.0**2, dtype=torch.float64))  # fx px per unit


def test_filter_keeps_each_gaussians_integral_and_has_exact_gradients():
    g = torch.Generator().manual_seed(0)
    scales = (torch.rand(5, 3, generator=g, dtype=torch.float64) * 0.1 + 0.01).requires_grad_()
    opac = torch.rand(5, generator=g, dtype=torch.float64).requires_grad_()
    var = torch.rand(5, generator=g, dtype=torch.float64) * 1e-3
    s2, o2 = mip.apply_filter(scales, opac, var)
    integral = lambda s, o: o * s.prod(-1)  # opacity x sqrt(det Sigma) (x (2 pi)^(3/2), common to both)
    torch.testing.assert_close(integral(s2, o2), integral(scales, opac))
    torch.testing.assert_close(s2**2, scales**2 + var[:, None])
    assert torch.autograd.gradcheck(lambda s, o: mip.apply_filter(s, o, var), (scales, opac))


@pytest.mark.slow
def test_example_backbone_is_a_row_of_the_grayscale_comparison(tmp_path):
    """The plugin's `variant` joins the study's sweep (stage=check: every job composes, builds and validates)."""
    import json
    import subprocess

    from conftest import arcsem_command

    sweep = tmp_path / "sweep"
    proc = subprocess.run([*arcsem_command(), "experiment=grayscale_comparison", "stage=check",
                           "variant=gs3d,gs3d_mip", f"hydra.sweep.dir={sweep}",
                           "dataset.width=96", "dataset.height=64", f"cache_dir={tmp_path / 'cache'}",
                           "dataset.n_horizontal=4", "dataset.n_vertical=2"],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path, check=False,
                          env={**__import__("os").environ, "ARCSEM_CACHE": str(tmp_path / "cache")})
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = {json.loads(p.read_text())["backbone"] for p in sweep.glob("*/metrics.json")}
    assert rows == {"gs3d", "gs3d_mip"}
