"""``arcsem-plugins``: every registered backbone and loss, where it comes from, what it provides or
requires, and its ``Config`` fields with their defaults.

Each plugin is loaded on its own; one that fails to load is listed with its error.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from importlib import metadata
from typing import Any

from .errors import with_error_handling

__all__ = ["format_rows", "main", "plugin_rows"]


def _origin(registry: Any, name: str) -> str:
    """``in-tree <module>`` or ``<module> [<distribution>]`` (or ``registered in <module>``)."""
    eps = {ep.name: ep for ep in metadata.entry_points(group=registry.group)}
    ep = eps.get(name)
    if ep is None:
        cls = registry.registered(name)
        return f"registered in {cls.__module__}" if cls is not None else "?"
    dist = getattr(ep, "dist", None)
    dist_name = dist.name if dist is not None else "?"
    if dist_name == "arcsem" and ep.value.startswith("arcsem."):
        return f"in-tree {ep.value}"
    return f"{ep.value} [{dist_name}]"


def _config_fields(cls: type) -> str:
    cfg = getattr(cls, "Config", None)
    if cfg is None or not dataclasses.is_dataclass(cfg):
        return "(no Config dataclass)"
    parts = []
    for f in dataclasses.fields(cfg):
        if f.default is not dataclasses.MISSING:
            parts.append(f"{f.name}={f.default!r}")
        elif f.default_factory is not dataclasses.MISSING:
            parts.append(f"{f.name}={f.default_factory()!r}")
        else:
            parts.append(f"{f.name}=<required>")
    return ", ".join(parts) or "(none)"


def plugin_rows(kinds: list[str] | None = None) -> list[dict[str, str]]:
    """One dict per plugin: kind, name, origin, caps (provides/requires), config or error."""
    from ..plugins import BACKBONES, LOSSES

    rows = []
    for registry in (BACKBONES, LOSSES):
        if kinds and registry.kind not in kinds:
            continue
        for name in registry.names():
            row = {"kind": registry.kind, "name": name, "origin": _origin(registry, name)}
            try:
                cls = registry.get(name)
            except Exception as exc:  # noqa: BLE001 (listed, not fatal)
                row.update(caps="-", config="", error=str(exc).splitlines()[0] if str(exc) else repr(exc))
                rows.append(row)
                continue
            attr = "provides" if registry.kind == "backbone" else "requires"
            caps = sorted(getattr(cls, attr, ()) or ())
            row.update(caps=f"{attr}: {', '.join(caps) or '-'}", config=_config_fields(cls), error="")
            rows.append(row)
    return rows


def format_rows(rows: list[dict[str, str]]) -> str:
    """A text table: one line per plugin, its config (or error) indented on the next line."""
    head = {"kind": "KIND", "name": "NAME", "origin": "ORIGIN", "caps": "PROVIDES / REQUIRES"}
    cols = ["kind", "name", "origin"]
    width = {c: max(len(r[c]) for r in [head, *rows]) for c in cols}
    line = lambda r: "  ".join(r[c].ljust(width[c]) for c in cols) + "  " + r["caps"]
    out = [line(head)]
    for r in rows:
        out.append(line(r))
        out.append(f"    {'ERROR: ' + r['error'] if r['error'] else 'config: ' + r['config']}")
    return "\n".join(out)


@with_error_handling
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="arcsem-plugins", description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=["backbone", "loss"], action="append", help="only this kind")
    parser.add_argument("--strict", action="store_true", help="exit 1 if a plugin fails to load")
    args = parser.parse_args(argv)
    rows = plugin_rows(args.kind)
    print(format_rows(rows) if rows else "no plugins registered")
    return 1 if args.strict and any(r["error"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
