"""The fused kernels' loader: a build killed half-way (its PyTorch ``lock`` file left behind) does not make the next
run wait forever; it is removed under arcsem's OS lock (which dies with its process) and said so."""
from __future__ import annotations

import subprocess
import sys

import pytest

from arcsem import cext
from arcsem.backbones.gaussians.fused import EXTENSION


def test_a_stale_build_lock_does_not_hang_the_next_load():
    name = cext.build_name(EXTENSION)
    folder = cext.build_dir(name)
    if not (folder / f"{name}.so").exists():
        pytest.skip(f"the fused rasteriser is not built here ({folder})")
    with cext._build_lock(name):  # no arcsem process is inside a build meanwhile
        (folder / "lock").write_text("")  # what a SIGKILL during the build leaves
    code = "from arcsem.backbones.gaussians.fused import load_extension; assert load_extension() is not None"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=150, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "removed a stale build lock of fused C++ Gaussian rasteriser" in proc.stderr
    assert not (folder / "lock").exists()
