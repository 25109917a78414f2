"""Guarded workaround for ``import torchvision`` failing with a CPU torch and a CUDA torchvision wheel.

The only torchvision wheel reachable here is a CUDA build whose compiled ops (``torchvision._C``) do
not load against the CPU torch. Its ``_meta_registrations`` module then registers fake kernels for
``torchvision::nms`` and ``torchvision::qnms`` and fails with ``operator torchvision::nms does not
exist`` (pytorch/vision#9085). Defining the two op *schemas* (no kernels) before the first import
lets torchvision, its models and ``lpips`` import; ``torchvision.ops`` and ``torchvision.io`` stay
unusable. Nothing is defined when the ops already exist (a matching build), so a working install is
left untouched.
"""
from __future__ import annotations

import sys
from types import ModuleType

__all__ = ["MISSING_OP_SCHEMAS", "ensure_torchvision_ops", "import_torchvision"]

# Schemas of the ops that torchvision registers fake kernels for at import time.
MISSING_OP_SCHEMAS = {
    "nms": "nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
    "qnms": "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
}
_LIB = None  # keeps the torch.library.Library alive (the definitions vanish with it)


def _op_exists(name: str) -> bool:
    import torch

    try:
        torch._C._dispatch_find_schema_or_throw(f"torchvision::{name}", "")
        return True
    except RuntimeError:
        return False


def ensure_torchvision_ops() -> list[str]:
    """Define the schemas of missing torchvision ops; returns the names defined (empty if none)."""
    global _LIB
    if "torchvision" in sys.modules:
        return []
    missing = [n for n in MISSING_OP_SCHEMAS if not _op_exists(n)]
    if not missing:
        return []
    import torch.library

    if _LIB is None:
        _LIB = torch.library.Library("torchvision", "FRAGMENT")  # noqa: TOR901 (schema only, no kernels)
    for name in missing:
        _LIB.define(MISSING_OP_SCHEMAS[name])
    return missing


def _compiled_ops_load() -> bool:
    """True if torchvision's compiled ``_C`` library loads (it defines the real ops), without importing
    the torchvision package itself."""
    import importlib.util
    from pathlib import Path

    import torch

    spec = importlib.util.find_spec("torchvision")
    if spec is None or not spec.submodule_search_locations:
        return False
    libs = sorted(Path(next(iter(spec.submodule_search_locations))).glob("_C*.so")) + \
        sorted(Path(next(iter(spec.submodule_search_locations))).glob("_C*.pyd"))
    for lib in libs:
        try:
            torch.ops.load_library(str(lib))
            return True
        except (OSError, RuntimeError):
            return False
    return False


def import_torchvision() -> ModuleType:
    """``import torchvision`` with the workaround applied first when (and only when) it is needed.

    The compiled ops are tried first (loading ``torchvision/_C``, as torchvision itself does); only
    when they do not load and the schemas are still missing are they defined here.
    """
    if "torchvision" not in sys.modules and not _compiled_ops_load():
        ensure_torchvision_ops()
    import torchvision

    return torchvision
