"""The import graph of a source tree, read with ``ast``, and the layer rules of docs/architecture.md.

Used by tests/test_import_layers.py. A *module* is a ``.py`` file (a package is its ``__init__.py``),
named as Python imports it (``backbones/gs2d/render.py`` -> ``arcsem.backbones.gs2d.render``). An *edge*
``a -> b`` is one ``import``/``from ... import`` statement anywhere in ``a`` (module level, inside a
function, under ``if TYPE_CHECKING``; relative ones resolved) that names module ``b``: ``from p import x``
names ``p.x`` where that is a module, else ``p``. Importing ``p.q.r`` also runs ``p/__init__.py`` and
``p/q/__init__.py``, so the edge goes to those packages too, except to the importing module's own
packages (those run first anyway, whatever it imports). Imports of anything outside the tree are ignored.

The layers block (a fenced ````` ```layers ````` block in the doc) has one line per ``layer unit files...``;
layers are listed lowest first, a unit may take several lines; a file pattern ending in ``/`` is that
folder and everything under it, and the longest pattern that matches a module's file decides its unit.
"""
from __future__ import annotations

import ast
import re
from collections import deque
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Edge", "Graph", "Layers", "build_graph", "cycles", "layer_problems", "parse_layers"]


@dataclass(frozen=True)
class Edge:
    """``src`` imports ``dst`` (module names) at ``path:line`` (``names``: what the statement takes)."""

    src: str
    dst: str
    path: str
    line: int
    names: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"


@dataclass
class Graph:
    """``modules``: name -> repo-relative file; ``edges``: every import edge inside the tree."""

    modules: dict[str, str]
    edges: list[Edge]


def _module_names(root: Path, folders: dict[str, str]) -> dict[str, tuple[str, bool]]:
    """``{module name: (repo-relative path, is package)}`` of every ``.py`` file under ``folders``
    (folder -> the package name it is imported as)."""
    out = {}
    for folder, package in folders.items():
        for f in sorted((root / folder).rglob("*.py")):
            parts = list(f.relative_to(root / folder).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            name = ".".join([package, *(parts[:-1] if is_pkg else parts)])
            out[name] = (f.relative_to(root).as_posix(), is_pkg)
    return out


def _ancestors(name: str) -> list[str]:
    """``a.b.c`` -> ``[a.b, a]``."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(len(parts) - 1, 0, -1)]


def _known(name: str, modules) -> str | None:
    """The longest prefix of ``name`` that is a module of the tree (None: outside it)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _targets(node: ast.Import | ast.ImportFrom, src: str, is_pkg: bool, modules) -> list[tuple[str, tuple]]:
    """The modules of the tree that one import statement names, each with the names it takes."""
    if isinstance(node, ast.Import):
        return [(t, ()) for t in (_known(a.name, modules) for a in node.names) if t]
    base = node.module or ""
    if node.level:
        package = src if is_pkg else src.rpartition(".")[0]
        for _ in range(node.level - 1):
            package = package.rpartition(".")[0]
        base = f"{package}.{base}" if base else package
    out: dict[str, tuple] = {}
    for alias in node.names:
        sub = f"{base}.{alias.name}"
        if sub in modules:
            out.setdefault(sub, ())
        elif (t := _known(base, modules)) is not None:
            out[t] = out.get(t, ()) + ((alias.name,) if t == base else ())
    return list(out.items())


def build_graph(root: Path, folders: dict[str, str]) -> Graph:
    """The import graph of the ``.py`` files under ``folders`` of ``root`` (see the module docstring)."""
    named = _module_names(Path(root), folders)
    modules = {name: path for name, (path, _) in named.items()}
    edges = []
    for src, (path, is_pkg) in named.items():
        tree = ast.parse((Path(root) / path).read_text(encoding="utf-8"), filename=path)
        own = set(_ancestors(src))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for dst, names in _targets(node, src, is_pkg, modules):
                for d in [dst, *_ancestors(dst)]:
                    if d != src and d not in own and d in modules:
                        edges.append(Edge(src, d, path, node.lineno, names if d == dst else ()))
    return Graph(modules, edges)


def cycles(graph: Graph, allowed: set[tuple[str, str]] = frozenset()) -> list[list[Edge]]:
    """One shortest cycle (as its edges) through each strongly connected set of modules, ignoring the
    ``allowed`` ``(src, dst)`` edges."""
    succ: dict[str, dict[str, Edge]] = {}
    for e in graph.edges:
        if (e.src, e.dst) not in allowed:
            succ.setdefault(e.src, {}).setdefault(e.dst, e)
    found, seen = [], set()
    for start in sorted(graph.modules):
        if start in seen:
            continue
        path = _shortest_path_back(start, succ)
        if path:
            seen.update(e.src for e in path)
            found.append(path)
    return found


def _shortest_path_back(start: str, succ) -> list[Edge] | None:
    """Edges of a shortest path ``start -> ... -> start`` (breadth first), or None."""
    prev: dict[str, Edge] = {}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w, e in sorted(succ.get(v, {}).items()):
            if w == start:
                path = [e]
                while path[0].src != start:
                    path.insert(0, prev[path[0].src])
                return path
            if w not in prev:
                prev[w] = e
                queue.append(w)
    return None


@dataclass
class Layers:
    """``order``: layer names, lowest first; ``units``: unit -> layer; ``patterns``: file pattern -> unit."""

    order: list[str]
    units: dict[str, str]
    patterns: dict[str, str]

    def unit_of(self, path: str) -> str | None:
        """The unit of a repo-relative file (longest matching pattern), or None."""
        best = max((p for p in self.patterns if path == p or (p.endswith("/") and path.startswith(p))),
                   key=len, default=None)
        return None if best is None else self.patterns[best]

    def rank(self, unit: str) -> int:
        return self.order.index(self.units[unit])


def parse_layers(markdown: str) -> Layers:
    """The layers block of ``markdown`` (see the module docstring); ValueError where it is malformed."""
    blocks = re.findall(r"^```layers\n(.*?)^```", markdown, flags=re.DOTALL | re.MULTILINE)
    if len(blocks) != 1:
        raise ValueError(f"expected one ```layers block, found {len(blocks)}")
    layers = Layers([], {}, {})
    for n, raw in enumerate(blocks[0].splitlines(), 1):
        line = raw.split("#", 1)[0].split()
        if not line:
            continue
        if len(line) < 3:
            raise ValueError(f"layers block line {n}: expected 'layer unit file...', got {raw!r}")
        layer, unit, files = line[0], line[1], line[2:]
        if layers.units.setdefault(unit, layer) != layer:
            raise ValueError(f"layers block line {n}: unit {unit!r} is on two layers")
        if layer not in layers.order:
            layers.order.append(layer)
        for f in files:
            if layers.patterns.setdefault(f, unit) != unit:
                raise ValueError(f"layers block line {n}: {f} is in two units")
    return layers


def layer_problems(graph: Graph, layers: Layers, doc: str, allowed: set[tuple[str, str]] = frozenset()) -> list[str]:
    """Every module without a unit, every import that runs to a higher layer or sideways to another unit
    of the same layer, and every private name (``_x``) imported from another unit; one line each, saying
    what to do (one line per statement and unit it reaches). ``doc``: the layers document's name."""
    out = [f"{path}: on no layer; add it to the layers block of {doc}"
           for path in graph.modules.values() if layers.unit_of(path) is None]
    seen = set()
    for e in graph.edges:
        su, du = layers.unit_of(graph.modules[e.src]), layers.unit_of(graph.modules[e.dst])
        if su is None or du is None or su == du or (e.src, e.dst) in allowed or (e.where, du) in seen:
            continue
        seen.add((e.where, du))
        sl, dl = layers.units[su], layers.units[du]
        if layers.rank(du) > layers.rank(su):
            out.append(f"{e.where}: {e.src} (layer {sl}) imports {e.dst} from the higher layer {dl}: imports go "
                       f"down only; move what both need down to a layer at or below {sl} ({doc})")
        elif layers.rank(du) == layers.rank(su):
            out.append(f"{e.where}: {e.src} (unit {su}) imports {e.dst} sideways from unit {du} of the same layer "
                       f"{sl}: move what both need to a lower layer ({doc})")
        for name in e.names:
            if name.startswith("_") and not name.startswith("__"):
                out.append(f"{e.where}: {e.src} imports the private name {name} of {e.dst} (another unit): "
                           "give it a public name in a module both may import")
    return out
