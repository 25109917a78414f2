"""The fused C++ TSDF integration (``arcsem/mesh/cpp/tsdf.cpp``): one view fused in one pass over the voxels.

The PyTorch path of :meth:`arcsem.mesh.tsdf.TSDFVolume.integrate` is the reference (tests/test_mesh.py: the same
volume to float32 round-off); this one does the same arithmetic without the dozen full-grid temporaries of the
PyTorch ops: 5.8x on one view of the demo's grid (docs/mesh.md, "Fusion"). Taken for CPU tensors when the
extension builds (``mesh.impl: auto|torch|cpp``).
"""
from __future__ import annotations

from pathlib import Path

from torch import Tensor

from arcsem import cext

__all__ = ["EXTENSION", "integrate", "usable"]

EXTENSION = cext.Extension(prefix="arcsem_tsdf", sources=(Path(__file__).parent / "cpp" / "tsdf.cpp",),
                           what="fused C++ TSDF fusion", keys=("mesh.impl",),
                           cflags=(*cext.NATIVE_CFLAGS, "-fno-trapping-math", "-ffp-contract=off"))


def usable(impl: str, device) -> bool:
    """Whether ``impl`` (``auto|torch|cpp``, the config value ``mesh.impl``) takes the fused path on ``device``."""
    return cext.resolve_impl(impl, EXTENSION, str(device), key="mesh.impl") == "cpp"


def integrate(points: Tensor, w2c: Tensor, K: Tensor, ortho: bool, width: int, height: int, table: Tensor,
              rgb: Tensor | None, trunc: float, tsdf: Tensor, weight: Tensor, color: Tensor,
              color_weight: Tensor) -> None:
    """Fuse one view in place: ``points [N, 3]`` voxel centres, ``w2c [3, 4]``, ``K [3, 3]`` (float32, the frame
    of ``points``), ``table [H*W + 1]`` depth per pixel (NaN: nothing, +inf: free space; the last entry NaN),
    ``rgb [H*W, 3]`` or None; ``tsdf``, ``weight``, ``color_weight [N]`` and ``color [N, 3]`` are updated."""
    ext = cext.load(EXTENSION)
    empty = rgb if rgb is not None else points.new_zeros(0, 3)
    ext.tsdf_integrate(points, w2c.contiguous(), K.contiguous(), bool(ortho), int(width), int(height),
                       table.contiguous(), empty.contiguous(), float(trunc), tsdf, weight, color, color_weight)


if __name__ == "__main__":  # `python -m arcsem.mesh.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = cext.load(EXTENSION) is not None
    print(f"fused C++ TSDF fusion: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
