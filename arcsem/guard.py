"""The write guard: while a run is active, no file outside its run and cache folders is written, and no
input file is written at all.

Output names are made safe where they are formed (:func:`arcsem.names.view_names`,
:func:`out_path`); this module is the backstop under them. :func:`protect` installs a Python audit
hook (PEP 578) that sees every file the process opens for writing, renames, removes or creates a
folder for through Python (``open``, ``os.replace``, ``os.mkdir``, ``np.save``, ``imageio``, ``torch.save``
to a file object...), and refuses with :class:`~arcsem.errors.OutputError` a write that

* targets an input file (the dataset's files, listed by the caller), or a path inside an input
  folder that is not inside the run folder or the cache (the ``own`` folders); or
* lies outside every allowed folder (the run folder, the cache root, the torch hub and extension
  folders, Triton's kernel cache, the temporary folder).

Writes made by C code (OpenCV's ``imwrite``, ``torch.save`` given a path name) or other processes
(ffmpeg) are not seen: arcsem passes them only paths built with :func:`out_path` or inside the run folder. Outside :func:`protect` the hook does nothing.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from .errors import OutputError

__all__ = ["allowed_roots", "inside", "out_path", "protect"]

_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
# audit event -> index of the path argument that is written (os.rename: the destination)
_EVENTS = {"os.rename": 1, "os.remove": 0, "os.rmdir": 0, "os.mkdir": 0, "os.truncate": 0, "os.symlink": 1,
           "os.link": 1, "shutil.rmtree": 0, "shutil.move": 1, "shutil.copyfile": 1}
_state: dict = {"active": False, "allowed": (), "own": (), "inputs": frozenset(), "input_dirs": ()}


def _real(path: str | os.PathLike) -> str:
    return os.path.realpath(os.fspath(path))


def inside(path: str | os.PathLike, root: str | os.PathLike) -> bool:
    """True if ``path`` is ``root`` or lies below it (both resolved, symlinks followed)."""
    p, r = _real(path), _real(root)
    return p == r or p.startswith(r.rstrip(os.sep) + os.sep)


def _refusal(path: str) -> str | None:
    """Why writing ``path`` is refused under the active guard, or None."""
    real = _real(path)
    if real in _state["inputs"]:
        return "it is an input file of this run"
    if any(inside(real, d) for d in _state["input_dirs"]) and not any(inside(real, r) for r in _state["own"]):
        return "it lies in an input folder"
    if not any(inside(real, r) for r in _state["allowed"]) and real != os.devnull:
        return "it lies outside the run folder and the cache"
    return None


def _hook(event: str, args: tuple) -> None:
    if not _state["active"]:
        return
    if event == "open":
        path, mode, flags = args
        writes = (isinstance(mode, str) and any(c in mode for c in "wax+")) or (
            mode is None and isinstance(flags, int) and flags & _WRITE_FLAGS)
        if not writes:
            return
    elif event in _EVENTS:
        path = args[_EVENTS[event]]
    else:
        return
    if not isinstance(path, (str, os.PathLike)):  # file descriptors, bytes paths: not ours
        return
    why = _refusal(path)
    if why is not None:
        raise OutputError(f"refused to write {os.fspath(path)}: {why} (run folder: {_state['allowed'][0]})")


_installed = False


def allowed_roots(run_dir: str | os.PathLike, cache_dir: str | os.PathLike | None = None) -> list[Path]:
    """The folders a run may write: its run folder, the cache, torch's hub and extension folders, Triton's kernel
    cache, the temp folder."""
    roots = [Path(run_dir)]
    if cache_dir is not None:
        roots.append(Path(cache_dir))
    torch_home = os.environ.get("TORCH_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "torch")
    roots += [Path(torch_home), _extensions_root(), _triton_cache_root(), Path(tempfile.gettempdir())]
    return roots


def _triton_cache_root() -> Path:
    """Where Triton caches the kernels it compiles (``rasterizer=triton``): ``$TRITON_CACHE_DIR``, else
    ``.triton/cache`` under ``$TRITON_HOME`` or the home folder (as Triton's ``knobs.cache.dir``; refused, the first
    GPU run of the Triton kernels stopped before its first step)."""
    if os.environ.get("TRITON_CACHE_DIR"):
        return Path(os.environ["TRITON_CACHE_DIR"])
    return Path(os.environ.get("TRITON_HOME") or os.path.expanduser("~")) / ".triton" / "cache"


def _extensions_root() -> Path:
    """Where PyTorch's JIT builds extensions: ``$TORCH_EXTENSIONS_DIR``, else its user cache folder (``torch_extensions``
    beside ``$XDG_CACHE_HOME``/``~/.cache``: not under ``$TORCH_HOME``; a guard that assumed so refused the kernels' build
    folder to every run with ``TORCH_HOME`` set, which then trained on the PyTorch path, 3x slower)."""
    if os.environ.get("TORCH_EXTENSIONS_DIR"):
        return Path(os.environ["TORCH_EXTENSIONS_DIR"])
    from torch.utils.cpp_extension import get_default_build_root

    return Path(get_default_build_root())


@contextlib.contextmanager
def protect(allowed: Iterable[str | os.PathLike], inputs: Iterable[str | os.PathLike] = (),
            input_dirs: Iterable[str | os.PathLike] = (), own: Iterable[str | os.PathLike] | None = None,
            ) -> Iterator[None]:
    """Refuse writes outside the ``allowed`` folders, to ``inputs``, and inside ``input_dirs`` unless inside an
    ``own`` folder (default: the first allowed one). The first allowed folder is named in messages (the run
    folder). Nested calls are not supported."""
    global _installed
    if not _installed:
        sys.addaudithook(_hook)
        _installed = True
    old = dict(_state)
    allowed = [_real(a) for a in allowed]
    _state.update(allowed=tuple(allowed), own=tuple(_real(o) for o in own) if own is not None else tuple(allowed[:1]),
                  inputs=frozenset(_real(i) for i in inputs), input_dirs=tuple(_real(d) for d in input_dirs),
                  active=True)
    try:
        yield
    finally:
        _state.clear()
        _state.update(old)


def out_path(root: str | os.PathLike, name: str, suffix: str = "") -> Path:
    """``root/<name><suffix>`` for an output file, its folder created; ``name`` may hold ``/`` (sub-folders)
    but no absolute path or ``..``: OutputError otherwise, so a view name can never point outside ``root``."""
    parts = Path(name).parts
    if not name or Path(name).is_absolute() or any(p in ("..", "") for p in parts):
        raise OutputError(f"unsafe output name {name!r}: it must be a relative path without '..'")
    path = Path(root) / f"{name}{suffix}"
    if not inside(path, root):
        raise OutputError(f"unsafe output name {name!r}: {path} lies outside {root}")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path
