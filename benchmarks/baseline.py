"""The fused rasteriser of another commit, loaded beside the working tree's, for side-by-side timing.

``baseline_renderers(rev)`` writes that commit's ``backbones/gaussians/fused.py``, ``cpp/`` and the two render
modules into a temporary folder, builds its kernels as a second extension (:mod:`arcsem.cext`: its own build
folder, named by the hash of its sources) and returns ``{"2DGS": render_2dgs, "3DGS": render_3dgs}`` of that
commit, and ``"sh_colors"`` where that commit has the fused SH colours. Each call runs with that commit's
``fused`` module standing in for the working tree's (the render modules import it by name when they render).
Everything else (projection camera, SH, the PyTorch reference) is the working tree's. Benchmarks time these and
the working tree's alternately in one process, so a ratio is measured under one machine load.
"""
from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FILES = ("backbones/gaussians/fused.py", "backbones/gs2d/render.py", "backbones/gs3d/render.py")


def _git_show(rev: str, path: str) -> bytes:
    return subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, capture_output=True, check=True).stdout


def _materialise(rev: str, out: Path) -> None:
    names = subprocess.run(["git", "ls-tree", "--name-only", f"{rev}", "backbones/gaussians/cpp/"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for path in [*FILES, *names]:
        dst = out / path
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(_git_show(rev, path))


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@contextlib.contextmanager
def _standing_in(fused_module):
    """``arcsem.backbones.gaussians.fused`` is ``fused_module`` inside the block."""
    import arcsem.backbones.gaussians as pkg

    key = "arcsem.backbones.gaussians.fused"
    saved = sys.modules.get(key), getattr(pkg, "fused", None)
    sys.modules[key], pkg.fused = fused_module, fused_module
    try:
        yield
    finally:
        sys.modules[key], pkg.fused = saved


@functools.cache
def baseline_renderers(rev: str = "main") -> dict:
    """``{"2DGS": render_2dgs, "3DGS": render_3dgs}`` of commit ``rev`` (built on first use, about a minute)."""
    import arcsem.backbones.gaussians.fused  # noqa: F401 - the working tree's, restored after each call

    tmp = Path(tempfile.mkdtemp(prefix=f"arcsem_{rev.replace('/', '_')}_"))
    _materialise(rev, tmp)
    tag = rev.replace("/", "_").replace("-", "_").replace(".", "_")
    fused = _module(f"_baseline_{tag}_fused", tmp / FILES[0])
    fixed = os.environ.pop("ARCSEM_CPP_BUILD_NAME", None)  # a fixed build name would be the working tree's
    try:
        ext = fused.load_extension()
    finally:
        if fixed is not None:
            os.environ["ARCSEM_CPP_BUILD_NAME"] = fixed
    assert ext is not None, f"the kernels of {rev} did not build"
    fused.load_extension = lambda *a, **k: ext  # never loaded again (by name, it could be another build)
    fused.resolve_impl = lambda impl, device="cpu": "cpp"
    with _standing_in(fused):
        r2 = _module(f"_baseline_{tag}_gs2d", tmp / FILES[1])
        r3 = _module(f"_baseline_{tag}_gs3d", tmp / FILES[2])

    def wrap(fn):
        def call(*args, **kwargs):
            with _standing_in(fused):
                return fn(*args, **kwargs)
        return call

    out = {"2DGS": wrap(r2.render_2dgs), "3DGS": wrap(r3.render_3dgs)}
    if hasattr(fused, "sh_colors"):  # the fused SH colours, where the commit has them
        out["sh_colors"] = wrap(fused.sh_colors)
    return out
