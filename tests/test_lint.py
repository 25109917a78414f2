"""``make test`` runs ``ruff check`` on the whole tree before pytest (the target ``lint``), with the ruff that the
test extra installs and constraints.txt pins."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def recipe(target: str) -> tuple[list[str], list[str]]:
    """The prerequisites and the command lines of ``target`` in the Makefile."""
    text = (ROOT / "Makefile").read_text()
    m = re.search(rf"^{target}:([^\n]*)\n((?:\t[^\n]*\n)*)", text, re.MULTILINE)
    assert m, f"Makefile has no target '{target}'"
    return m.group(1).split(), [line.strip() for line in m.group(2).splitlines()]


def test_make_test_runs_ruff_before_pytest():
    prereqs, commands = recipe("test")
    assert prereqs[0] == "lint", "the test target's first prerequisite is the lint target (ruff before pytest)"
    assert any(c.startswith("$(BIN)/python -m pytest") for c in commands)
    assert recipe("lint")[1] == ["$(BIN)/ruff check ."]


def test_ruff_is_installed_by_the_test_extra_and_pinned():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    assert "ruff" in extra
    pins = re.findall(r"^ruff==\S+", (ROOT / "constraints.txt").read_text(), re.MULTILINE)
    assert len(pins) == 1, "constraints.txt pins ruff once"

