"""Build gsplat's CUDA extension once, as the module ``gsplat.csrc`` gsplat imports before it tries its JIT build.

gsplat from PyPI compiles its CUDA code the first time it is imported (minutes). On a machine that is given back
after each session that is paid for every time; this builds the same sources with gsplat's own flags for the
GPU at hand only (``TORCH_CUDA_ARCH_LIST``, default: this device's compute capability), installs the library
beside gsplat's package as ``csrc.so`` (gsplat's ``from gsplat import csrc``) and copies it to ``--out`` so a later
machine can install it with ``--install FILE`` instead of building.

    python benchmarks/gpu/gsplat_build.py --out .gpu/gsplat_csrc.so     # build (MAX_JOBS=16), install, copy
    python benchmarks/gpu/gsplat_build.py --install .gpu/gsplat_csrc.so # install a copy built for this GPU
"""
from __future__ import annotations

import argparse
import glob
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path


def build(build_dir: Path) -> Path:
    import gsplat
    import torch
    from torch.utils.cpp_extension import load

    root = Path(gsplat.__file__).parent / "cuda"
    if "TORCH_CUDA_ARCH_LIST" not in os.environ:
        major, minor = torch.cuda.get_device_capability()
        os.environ["TORCH_CUDA_ARCH_LIST"] = f"{major}.{minor}"
    os.environ.setdefault("MAX_JOBS", str(os.cpu_count() or 8))
    sources = sorted(glob.glob(str(root / "csrc" / "*.cu"))) + sorted(glob.glob(str(root / "csrc" / "*.cpp")))
    build_dir.mkdir(parents=True, exist_ok=True)
    load(name="csrc", sources=sources + [str(root / "ext.cpp")], build_directory=str(build_dir),
         extra_cflags=["-O3", "-Wno-attributes"], extra_cuda_cflags=["-O3", "-use_fast_math"],
         extra_include_paths=[str(root / "include"), str(root / "csrc" / "third_party" / "glm")], verbose=False)
    return build_dir / "csrc.so"


def install(lib: Path) -> Path:
    """Copy ``lib`` to ``gsplat/csrc.so`` (found by ``find_spec``: importing gsplat here would start its JIT build)."""
    from importlib.util import find_spec

    dest = Path(find_spec("gsplat").submodule_search_locations[0]) / "csrc.so"
    shutil.copy2(lib, dest)
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="copy the built library here")
    ap.add_argument("--install", default=None, help="install this prebuilt library instead of building")
    ap.add_argument("--build-dir", default="/tmp/gsplat_csrc_build")
    a = ap.parse_args()
    if a.install:
        print(f"gsplat: installed {install(Path(a.install))}")
    else:
        t0 = time.time()
        lib = build(Path(a.build_dir))
        print(f"gsplat: built {lib} ({lib.stat().st_size / 1e6:.1f} MB) in {time.time() - t0:.0f} s "
              f"for sm {os.environ['TORCH_CUDA_ARCH_LIST']}")
        install(lib)
        if a.out:
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(lib, a.out)
    # in a fresh process: this one holds the library under the name `csrc` already (pybind11 types register once)
    check = "import gsplat.cuda._backend as b; assert b._C is not None and b._C.__name__ == 'gsplat.csrc'"
    ok = subprocess.run([sys.executable, "-c", check], check=False).returncode == 0
    print("gsplat: imports the built library" if ok else "gsplat: the library does not import (see above)")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
