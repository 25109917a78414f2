"""C++ extensions: one loader and one ``rasterizer`` choice for every fused CPU kernel of the project.

A backbone with fused kernels names its sources once (:class:`Extension`); :func:`load` compiles them as a
PyTorch JIT extension the first time (about a minute with gcc; cached under ``$TORCH_EXTENSIONS_DIR`` or
``~/.cache/torch_extensions``) and returns None with one warning when no toolchain is available, so
``rasterizer: auto`` falls back to the PyTorch reference path. :func:`resolve_impl` turns the config value
``auto|torch|cpp`` into the path a render takes.

The build folder's name carries a hash of the sources, the headers beside them, the flags and the source
folder: every change (and every checkout) builds into its own folder, so a stale build is never loaded and a
running job's library is never overwritten. ``ARCSEM_NO_CPP=1`` disables every extension (the PyTorch path
is used); ``ARCSEM_CPP_BUILD_NAME`` fixes the name (incremental builds while editing a kernel). Builds are
serialised by an OS file lock (a killed build cannot leave a lock behind that makes every later run wait), and a
build says so on stderr while it runs.
"""
from __future__ import annotations

import hashlib
import os
import sys
import warnings
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

__all__ = ["CHOICES", "NATIVE_CFLAGS", "Extension", "build_dir", "build_name", "cpu_fingerprint", "load",
           "resolve_impl"]

CHOICES = ("auto", "torch", "cpp")
NATIVE_CFLAGS = ("-O3", "-fopenmp", "-march=native")
"""Flags for kernels written to be vectorised: the instruction set of the machine that builds (the JIT build runs
where the kernels run; the build folder's name then carries :func:`cpu_fingerprint`, so a cache shared by
machines of different kinds holds one build per kind)."""


def cpu_fingerprint() -> str:
    """The CPU's model and instruction-set flags (``/proc/cpuinfo``; the platform's name elsewhere)."""
    import platform

    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.machine() + platform.processor()
    keep = [ln for ln in lines if ln.split(":")[0].strip() in ("model name", "flags", "Features", "CPU part")]
    return "\n".join(sorted(set(keep)))


@dataclass(frozen=True)
class Extension:
    """What to build: ``prefix`` (e.g. ``arcsem_gaussians``), the ``.cpp`` files, and what it is for messages."""

    prefix: str
    sources: tuple[Path, ...]
    what: str
    keys: tuple[str, ...] = ("rasterizer",)  # the config keys that choose it (the fallback warning names them)
    cflags: tuple[str, ...] = field(default=("-O3", "-fopenmp"))
    ldflags: tuple[str, ...] = field(default=("-fopenmp",))


def build_name(ext: Extension) -> str:
    """``<prefix>_<12 hex>``: a hash of the flags, the source folder, the sources and the headers beside them (and of
    the CPU with ``-march=native``)."""
    folders = sorted({s.parent for s in ext.sources})
    h = hashlib.sha1(" ".join([*ext.cflags, *ext.ldflags, *map(str, folders)]).encode())
    if "-march=native" in ext.cflags:
        h.update(cpu_fingerprint().encode())
    headers = [p for d in folders for p in d.glob("*.h")]
    for f in sorted({*ext.sources, *headers}):
        h.update(f.name.encode() + f.read_bytes())
    return f"{ext.prefix}_{h.hexdigest()[:12]}"


def build_dir(name: str) -> Path:
    """Where PyTorch's JIT builds the extension ``name`` (``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``)."""
    from torch.utils.cpp_extension import _get_build_directory

    return Path(_get_build_directory(name, verbose=False))


def _prepared(name: str, what: str) -> Path:
    """The build folder, with PyTorch's ``lock`` removed when it is stale, and a word when a build is due.

    PyTorch marks a build in progress with a ``lock`` file that a killed build leaves behind; every later load then
    waits for it forever, saying nothing. Callers hold :func:`_build_lock` (an OS lock, released when its process
    dies), so no other arcsem process is building here and a ``lock`` found is stale."""
    folder = build_dir(name)
    stale = folder / "lock"
    if stale.exists():
        stale.unlink(missing_ok=True)
        warnings.warn(f"arcsem: removed a stale build lock of {what} ({stale}: a build killed before it finished)",
                      RuntimeWarning, stacklevel=3)
    if not (folder / f"{name}.so").exists():
        print(f"arcsem: building {what} (once for these sources, about a minute)...", file=sys.stderr, flush=True)
    return folder


def _build_lock(name: str):
    """An OS file lock per build (released by the kernel when its holder dies, unlike PyTorch's ``lock`` file)."""
    from filelock import FileLock

    root = build_dir(name).parent
    root.mkdir(parents=True, exist_ok=True)
    return FileLock(str(root / f".{name}.arcsem-lock"))


@cache
def load(ext: Extension, verbose: bool = False):
    """The compiled module, or None (with one warning naming ``ext.what``) when it cannot be built or loaded."""
    if os.environ.get("ARCSEM_NO_CPP"):
        return None
    try:
        from torch.utils.cpp_extension import load as jit_load

        name = os.environ.get("ARCSEM_CPP_BUILD_NAME") or build_name(ext)
        with _build_lock(name):
            _prepared(name, ext.what)
            return jit_load(
                name=name,
                sources=[str(s) for s in ext.sources],
                extra_cflags=list(ext.cflags),
                extra_ldflags=list(ext.ldflags),
                verbose=verbose,
            )
    except Exception as exc:  # noqa: BLE001 - no compiler, no headers, ...: fall back, say it once
        warnings.warn(f"arcsem: {ext.what} unavailable ({type(exc).__name__}: {str(exc)[:200]}); "
                      f"using the PyTorch path ({', '.join(k + '=torch' for k in ext.keys)})", RuntimeWarning,
                      stacklevel=2)
        return None


def resolve_impl(impl: str, ext: Extension, device: str = "cpu", key: str = "rasterizer") -> str:
    """``rasterizer`` config value (or another choice named ``key``) -> ``"cpp"`` or ``"torch"``.

    ``auto``: ``cpp`` for CPU tensors when the extension loads, else ``torch``; ``torch``: always the PyTorch
    path (any device); ``cpp``: must load and the tensors must be on the CPU (else a ConfigError).
    """
    from arcsem.errors import ConfigError

    if impl not in CHOICES:
        raise ConfigError(f"{key}: '{impl}' is not one of {', '.join(CHOICES)}")
    on_cpu = str(device).split(":")[0] == "cpu"
    if impl == "torch" or (impl == "auto" and not on_cpu):
        return "torch"
    ok = on_cpu and load(ext) is not None
    if impl == "cpp" and not ok:
        why = "tensors on the CPU" if not on_cpu else "a C++ toolchain (see the warning above)"
        raise ConfigError(f"{key}: 'cpp' ({ext.what}) needs {why}; use {key}=torch or auto")
    return "cpp" if ok else "torch"
