"""The fused kernels' loader: a build killed half-way (its PyTorch ``lock`` file left behind) does not make the next
run wait forever; it is removed under arcsem's OS lock (which dies with its process) and said so."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest
from arcsem.backbones.gaussians.fused import EXTENSION

from arcsem import cext


def test_a_stale_build_lock_does_not_hang_the_next_load(tmp_path):
    """On a copy of the built rasteriser (``TORCH_EXTENSIONS_DIR``: the shared build folder stays untouched by the
    planted lock). PyTorch alone waits for that lock forever; arcsem's loader removes it and loads."""
    name = cext.build_name(EXTENSION)
    folder = cext.build_dir(name)
    if not (folder / f"{name}.so").exists():
        pytest.skip(f"the fused rasteriser is not built here ({folder})")
    copy = tmp_path / name  # where PyTorch builds under TORCH_EXTENSIONS_DIR (no per-Python subfolder there)
    with cext._build_lock(name):  # a complete build to copy
        shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("lock"))
    (copy / "lock").write_text("")  # what a SIGKILL during the build leaves
    code = "from arcsem.backbones.gaussians.fused import load_extension; assert load_extension() is not None"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=150, check=False,
                          env={**os.environ, "TORCH_EXTENSIONS_DIR": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "removed a stale build lock of fused C++ Gaussian rasteriser" in proc.stderr
    assert "building" not in proc.stderr  # the copy was complete: nothing to build
    assert not (copy / "lock").exists()
