"""Every maintained benchmark script (``benchmarks/**/*.py``, ``*.sh``, outside ``benchmarks/archive/``) is listed
in benchmarks/results/README.md with its command; the archive says what it holds."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"


def scripts() -> list[str]:
    """The maintained scripts, as paths from the repository root (``benchmarks/bench_fused.py``)."""
    found = [p for ext in ("*.py", "*.sh") for p in BENCH.rglob(ext)]
    return sorted(p.relative_to(ROOT).as_posix() for p in found if "archive" not in p.relative_to(BENCH).parts)


def listed() -> dict[str, str]:
    """``script -> command`` from the table of the README's section "Benchmark scripts"."""
    text = (BENCH / "results" / "README.md").read_text()
    rows = re.findall(r"^\| `(benchmarks/[^`]+)` \|[^\n]*\| (.+) \|$", text, re.MULTILINE)
    return dict(rows)


def test_every_maintained_benchmark_is_listed_with_its_command():
    table = listed()
    missing = [s for s in scripts() if s not in table]
    assert not missing, f"not in benchmarks/results/README.md's 'Benchmark scripts' table: {missing}"
    stale = [s for s in table if not (ROOT / s).is_file()]
    assert not stale, f"listed but not in benchmarks/ (moved to archive/?): {stale}"
    assert all(cmd.strip() for cmd in table.values())


def test_archive_readme_describes_every_archived_script():
    archived = sorted(p.name for p in (BENCH / "archive").glob("*.py"))
    readme = (BENCH / "archive" / "README.md").read_text()
    assert archived and all(f"`{name}`" in readme for name in archived), archived
    assert "not maintained" in readme
