"""Where the project's Triton kernels run, and what they need from the host (the 2DGS rasteriser's,
``backbones/gaussians/triton2d.py``, and the fused losses', ``losses/triton_ssim.py``).

Triton compiles kernels for CUDA GPUs at first use (cached under ``~/.triton``). With ``TRITON_INTERPRET=1`` in the
environment when a kernel module is first imported, the kernels run on CPU tensors through Triton's interpreter
(slowly: the tests' path on a machine without a GPU). ``auto`` settings take the kernels on CUDA devices Triton
supports, where the host issuing one launch replaces it issuing tens of PyTorch operators.
"""
from __future__ import annotations

import functools
import os

import torch
from torch import Tensor

__all__ = ["auto_on", "available", "constants", "interpreted", "tl_dtype"]


def interpreted() -> bool:
    """Whether Triton runs the kernels through its CPU interpreter (``TRITON_INTERPRET=1``)."""
    return os.environ.get("TRITON_INTERPRET", "0") not in ("", "0")


def available(device) -> str | None:
    """None when Triton kernels can run on ``device``, else why not (one line)."""
    if not _importable():
        return "needs the triton package (installed with PyTorch's CUDA wheels; pip install triton)"
    dev = str(device).split(":")[0]
    if dev == "cuda" or (dev == "cpu" and interpreted()):
        return None
    return f"runs on CUDA tensors (the device is {device}; on the CPU only under TRITON_INTERPRET=1, for tests)"


def auto_on(device) -> bool:
    """Whether an ``auto`` choice takes Triton kernels on ``device``: a CUDA device of compute capability 8.0 or newer
    (the GPUs Triton supports; measured on 9.0), with Triton importable."""
    dev = torch.device(device)
    return dev.type == "cuda" and _importable() and _capability(dev) >= (8, 0)


@functools.cache
def _capability(dev: torch.device) -> tuple[int, int]:
    return torch.cuda.get_device_capability(dev)


@functools.cache
def _importable() -> bool:
    try:
        import triton  # noqa: F401
    except ImportError:
        return False
    return True


_CONSTANTS: dict = {}


def constants(like: Tensor, values: tuple[float, ...]) -> Tensor:
    """``values`` as a tensor on ``like``'s device and dtype, made once per (device, dtype, values): kernels read
    them in the run's precision (Python floats reach Triton as float32) without a transfer to the device a step."""
    key = (like.device, like.dtype, tuple(float(v) for v in values))
    if key not in _CONSTANTS:
        _CONSTANTS[key] = torch.tensor(key[2], dtype=like.dtype).to(like.device)
    return _CONSTANTS[key]


def tl_dtype(t: Tensor):
    """Triton's type for ``t``'s dtype: float32 or float64 (TypeError otherwise)."""
    import triton.language as tl

    if t.dtype == torch.float32:
        return tl.float32
    if t.dtype == torch.float64:
        return tl.float64
    raise TypeError(f"triton kernels: float32 or float64 tensors, got {t.dtype}")
