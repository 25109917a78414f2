"""A study's table as files: CSV (numbers), Markdown and LaTeX (booktabs); :func:`write_tables` writes them all."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from .collect import Collection
from .tables import LAYOUTS, ROW_HEADER, Table, build_table

__all__ = ["to_latex", "to_markdown", "write_tables"]


def to_markdown(t: Table) -> str:
    """GitHub Markdown: a header row ``group label`` per column, bold as ``**x**``, notes below."""
    head = [ROW_HEADER.get(t.study, "Row")] + [f"{c.label} ({c.group})" for c in t.columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" + "---:|" * len(t.columns)]
    for label, row in zip(t.labels, t.cells):
        lines.append("| " + " | ".join([label] + [f"**{x}**" if b else x for x, b in row]) + " |")
    notes = [f"{i}. {n}" for i, n in enumerate(t.notes, 1)]
    return f"### {t.study}\n\n" + "\n".join(lines) + "\n\nNotes:\n\n" + "\n".join(notes) + "\n"


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "_": r"\_", "#": r"\#", "$": r"\$",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\^{}", "±": r"$\pm$",
        "|": r"\textbar{}", "<": r"\textless{}", ">": r"\textgreater{}"}


def _tex(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (one pass, so escapes are not re-escaped)."""
    return "".join(_TEX.get(ch, ch) for ch in str(text)).replace("--", "-{}-")


def to_latex(t: Table) -> str:
    """A booktabs table with grouped headers (``\\cmidrule``), ``\\textbf`` best values, notes in the caption."""
    groups: list[tuple[str, int]] = []
    for c in t.columns:
        if groups and groups[-1][0] == c.group:
            groups[-1] = (c.group, groups[-1][1] + 1)
        else:
            groups.append((c.group, 1))
    top, rules, start = [""], [], 2
    for g, n in groups:
        top.append(rf"\multicolumn{{{n}}}{{c}}{{{_tex(g)}}}")
        rules.append(rf"\cmidrule(lr){{{start}-{start + n - 1}}}")
        start += n
    head = [_tex(ROW_HEADER.get(t.study, "Row"))] + [_tex(c.label) for c in t.columns]
    body = []
    for label, row in zip(t.labels, t.cells):
        cells = [rf"\textbf{{{_tex(x)}}}" if b else _tex(x) for x, b in row]
        body.append(" & ".join([_tex(label)] + cells) + r" \\")
    caption = _tex(t.study.replace("_", " ")) + ". " + " ".join(_tex(n) for n in t.notes)
    return "\n".join([
        r"\begin{table}[t]", r"\centering", r"\small",
        r"\begin{tabular}{l" + "r" * len(t.columns) + "}", r"\toprule",
        " & ".join(top) + r" \\", " ".join(rules), " & ".join(head) + r" \\", r"\midrule",
        *body, r"\bottomrule", r"\end{tabular}",
        rf"\caption{{{caption}}}", rf"\label{{tab:{t.study}}}", r"\end{table}", ""])


def write_tables(coll: Collection, out: Path) -> dict[str, Table]:
    """Write ``<study>.csv|.md|.tex`` for every study found, and ``all_runs.csv``; returns the tables."""
    out.mkdir(parents=True, exist_ok=True)
    coll.runs.to_csv(out / "all_runs.csv", index=False)
    studies = {s for s in coll.runs.get("study", pd.Series(dtype=str)).dropna()} | {
        m.study for m in coll.missing if m.study}
    tables = {}
    for study in [s for s in LAYOUTS if s in studies]:
        t = build_table(coll, study)
        t.numbers.to_csv(out / f"{study}.csv", index=False)
        (out / f"{study}.md").write_text(to_markdown(t))
        (out / f"{study}.tex").write_text(to_latex(t))
        tables[study] = t
    return tables
