"""View names: unique, readable, and safe to use as output file names.

A view is named after its image file's stem (``r_013``). Where several images share a stem
(``train/r_0.png`` and ``test/r_0.png``; ``../camA/img_000.png`` and ``../camB/img_000.png``) each of
them is named by its path relative to the folder the colliding files have in common (``train/r_0``,
``camA/img_000``). Names never hold an absolute path or ``..``, characters other than letters, digits,
``.``, ``_``, ``-`` and ``/`` become ``_``, and what still collides gets ``_2``, ``_3``... in file order.
Outputs are written under these names (``renders/train/camA/img_000.png``), so they stay in the run folder.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["safe_name", "view_names"]

_BAD = re.compile(r"[^A-Za-z0-9._-]")


def safe_name(parts: list[str] | tuple[str, ...]) -> str:
    """Path components -> ``a/b/c`` with unsafe characters replaced and empty, ``.`` and ``..`` parts dropped."""
    clean = [_BAD.sub("_", p) for p in parts if p not in ("", ".", "..")]
    clean = [p.lstrip(".") or "_" for p in clean]  # no hidden files, no '..' rebuilt from dots
    return "/".join(clean) or "view"


def view_names(files: list[str | os.PathLike]) -> list[str]:
    """One safe, unique name per file of ``files`` (see the module docstring)."""
    paths = [Path(os.path.abspath(f)) for f in files]
    stems = [p.stem for p in paths]
    names = []
    for p, stem in zip(paths, stems):
        group = [q for q, s in zip(paths, stems) if s == stem]
        if len(group) == 1:
            names.append(safe_name([stem]))
            continue
        common = Path(os.path.commonpath([str(q.parent) for q in group]))
        names.append(safe_name(p.with_suffix("").relative_to(common).parts))
    out: list[str] = []
    used: set[str] = set()
    for n in names:
        cand, k = n, 1
        while cand in used:
            k += 1
            cand = f"{n}_{k}"
        used.add(cand)
        out.append(cand)
    return out
