"""The import graph of arcsem/, backbones/ and losses/ follows the layers of docs/architecture.md.

The graph is read from the source (tests/layers_util.py); the layers from the ```layers block of the doc,
so the two cannot drift apart. Fails on a cycle and on an import that runs up, sideways between two units
of one layer, or takes a private name of another unit.
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from layers_util import build_graph, cycles, layer_problems, parse_layers

ROOT = Path(__file__).resolve().parents[1]
DOC = "docs/architecture.md"
FOLDERS = {"arcsem": "arcsem", "backbones": "arcsem.backbones", "losses": "arcsem.losses"}

# Edges owed to a refactoring still to come, each with its reason (test_owed_edges_still_exist says when one is
# gone). The last one, preflight -> app over the stage tables, went with the stage registry (arcsem/stages.py).
OWED_TO_STAGE_REGISTRY: set[tuple[str, str]] = set()


@pytest.fixture(scope="module")
def graph():
    return build_graph(ROOT, FOLDERS)


@pytest.fixture(scope="module")
def layers():
    return parse_layers((ROOT / DOC).read_text(encoding="utf-8"))


def _describe(cycle) -> str:
    steps = " -> ".join(f"{e.src} ({e.where})" for e in cycle)
    return f"import cycle: {steps} -> {cycle[0].src}"


def test_no_import_cycles(graph):
    found = [_describe(c) for c in cycles(graph, OWED_TO_STAGE_REGISTRY)]
    assert not found, ("\n".join(found) + "\nBreak each cycle: move what both modules need down into the lower one "
                       "(or a module below both); a function-local import does not break a cycle.")


def test_imports_follow_the_layers(graph, layers):
    problems = layer_problems(graph, layers, DOC, OWED_TO_STAGE_REGISTRY)
    assert not problems, "\n".join(problems)


def test_owed_edges_still_exist(graph):
    """Each allow-listed edge still exists; when one is gone, remove it from OWED_TO_STAGE_REGISTRY."""
    present = {(e.src, e.dst) for e in graph.edges}
    stale = sorted(OWED_TO_STAGE_REGISTRY - present)
    assert not stale, f"{stale}: no longer imported; remove from OWED_TO_STAGE_REGISTRY in {__file__}"


def test_every_unit_of_the_doc_holds_code(graph, layers):
    """A unit whose files are all gone is a stale line of the layers block (arcsem/stages.py may be absent)."""
    used = {layers.unit_of(p) for p in graph.modules.values()}
    assert set(layers.units) <= used, f"units without code in {DOC}: {sorted(set(layers.units) - used)}"


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(textwrap.dedent(text))


TINY_DOC = """
```layers
low    base   pkg/__init__.py pkg/util.py pkg/a.py pkg/b.py
low    other  pkg/other.py
high   top    pkg/top/
```
"""


def test_check_reports_a_cycle_an_upward_a_sideways_and_a_private_import(tmp_path):
    """A tiny package with one of each kind of fault: every one is reported with its file and line."""
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/util.py": "def helper():\n    from .top.run import main  # up, inside a function\n    return main\n",
        "pkg/a.py": "from . import b\nX = 1\n",
        "pkg/b.py": "def f():\n    from .a import X  # the cycle a -> b -> a, hidden in a function\n    return X\n",
        "pkg/other.py": "from pkg.util import _private\n",
        "pkg/top/__init__.py": "",
        "pkg/top/run.py": "from ..util import helper\n\ndef main():\n    return helper\n",
    })
    graph = build_graph(tmp_path, {"pkg": "pkg"})
    found = cycles(graph)
    assert [sorted(e.src for e in c) for c in found] == [["pkg.a", "pkg.b"], ["pkg.top.run", "pkg.util"]]
    assert "pkg/b.py:2" in _describe(found[0]) and "pkg/a.py:1" in _describe(found[0])

    problems = layer_problems(graph, parse_layers(TINY_DOC), "the doc")
    assert len(problems) == 3, problems
    assert problems[0].startswith("pkg/other.py:1: pkg.other (unit other) imports pkg.util sideways from unit base")
    assert problems[1].startswith("pkg/other.py:1: pkg.other imports the private name _private of pkg.util")
    assert problems[2].startswith("pkg/util.py:2: pkg.util (layer low) imports pkg.top.run from the higher layer high")
    assert "move what both need down" in problems[2]


def test_importing_a_submodule_runs_its_package(tmp_path):
    """``from pkg.top.run import x`` runs pkg/top/__init__.py too: a cycle through a package's __init__ counts."""
    _write(tmp_path, {"pkg/__init__.py": "", "pkg/low.py": "from pkg.top.run import x\n",
                      "pkg/top/__init__.py": "from ..low import y\n", "pkg/top/run.py": "x = 1\n"})
    found = cycles(build_graph(tmp_path, {"pkg": "pkg"}))
    assert [[(e.src, e.dst) for e in c] for c in found] == [[("pkg.low", "pkg.top"), ("pkg.top", "pkg.low")]]


def test_check_reports_modules_outside_every_layer(tmp_path):
    _write(tmp_path, {"pkg/__init__.py": "", "pkg/util.py": "", "pkg/new.py": ""})
    problems = layer_problems(build_graph(tmp_path, {"pkg": "pkg"}), parse_layers(TINY_DOC), "the doc")
    assert problems == ["pkg/new.py: on no layer; add it to the layers block of the doc"]


def test_allowed_edges_are_skipped(tmp_path):
    _write(tmp_path, {"pkg/__init__.py": "", "pkg/a.py": "from . import b\n", "pkg/b.py": "from . import a\n"})
    graph = build_graph(tmp_path, {"pkg": "pkg"})
    assert len(cycles(graph)) == 1
    assert cycles(graph, {("pkg.b", "pkg.a")}) == []


def test_layers_block_errors_name_the_line():
    with pytest.raises(ValueError, match="line 2: unit 'u' is on two layers"):
        parse_layers("```layers\nlow u a.py\nhigh u b.py\n```\n")
    with pytest.raises(ValueError, match="one ```layers block, found 0"):
        parse_layers("no block here")
