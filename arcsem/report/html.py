"""One static HTML page: per study the table, its notes, links to CSV/Markdown/LaTeX, grids and videos.

Every link is relative to the page; videos are copied next to it (``videos/<study>/...``) so the
report folder is self-contained and can be committed or moved.
"""
from __future__ import annotations

import html
import shutil
from datetime import datetime, timezone
from pathlib import Path

from .tables import ROW_HEADER, Table

__all__ = ["copy_videos", "render_table", "write_page"]

STYLE = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}th,td{padding:3px 8px;border-bottom:1px solid #ccc}
td{text-align:right}td:first-child,th:first-child{text-align:left}th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd}figure{display:inline-block;margin:4px}video{max-width:380px}.notes{font-size:90%;color:#444}"""


def render_table(t: Table) -> str:
    """``<table>`` with grouped headers and ``<b>`` for the best value of each column."""
    groups: list[list] = []
    for c in t.columns:
        if groups and groups[-1][0] == c.group:
            groups[-1][1] += 1
        else:
            groups.append([c.group, 1])
    e = html.escape
    top = "<tr><th></th>" + "".join(f'<th colspan="{n}">{e(g)}</th>' for g, n in groups) + "</tr>"
    head = f"<tr><th>{e(ROW_HEADER.get(t.study, 'Row'))}</th>" + "".join(
        f"<th>{e(c.label)}</th>" for c in t.columns) + "</tr>"
    body = "".join("<tr><td>" + e(label) + "</td>" + "".join(
        f"<td><b>{e(x)}</b></td>" if b else f"<td>{e(x)}</td>" for x, b in row) + "</tr>"
        for label, row in zip(t.labels, t.cells))
    return f"<table>{top}{head}{body}</table>"


def copy_videos(study: str, runs: dict[str, Path], out: Path) -> list[tuple[str, Path]]:
    """Copy every ``*.mp4`` of the runs (and of their shared stage-1 model, the ``stage1/`` link, which
    ``rglob`` does not follow) into ``out/videos/<study>/``; returns ``[(caption, path)]``."""
    found = []
    for label, run in runs.items():
        shared = Path(run) / "stage1"
        mp4s = sorted(Path(run).rglob("*.mp4")) + (sorted(shared.resolve().rglob("*.mp4")) if shared.is_symlink() else [])
        for mp4 in mp4s:
            if out.resolve() in mp4.resolve().parents:  # the report's own copies (out inside a run)
                continue
            safe = "".join(ch if ch.isalnum() else "_" for ch in label)
            dst = out / "videos" / study / f"{safe}_{mp4.stem}.mp4"
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(mp4, dst)
            found.append((f"{label}: {mp4.stem}", dst))
    return found


def _section(t: Table, grids: list[tuple[str, Path]], videos: list[tuple[str, Path]], out: Path) -> str:
    e = html.escape
    rel = lambda p: e(Path(p).relative_to(out).as_posix())
    links = " · ".join(f'<a href="{e(t.study)}.{ext}">{ext.upper()}</a>' for ext in ("csv", "md", "tex"))
    parts = [f'<h2 id="{e(t.study)}">{e(t.study.replace("_", " "))}</h2>', render_table(t),
             '<ol class="notes">' + "".join(f"<li>{e(n)}</li>" for n in t.notes) + "</ol>",
             f"<p>Download: {links}</p>"]
    for title, png in grids:
        parts.append(f"<h3>{e(title)}</h3><p><img src=\"{rel(png)}\" alt=\"{e(title)}\"></p>")
    if videos:
        parts.append("<h3>videos</h3><div>" + "".join(
            f'<figure><video controls muted loop src="{rel(v)}"></video><figcaption>{e(c)}</figcaption></figure>'
            for c, v in videos) + "</div>")
    return "\n".join(parts)


def write_page(out: Path, tables: dict[str, Table], grids: dict[str, list[tuple[str, Path]]],
               videos: dict[str, list[tuple[str, Path]]], sources: list[str], n_runs: int) -> Path:
    """Write ``out/index.html`` and return its path."""
    e = html.escape
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    toc = " · ".join(f'<a href="#{e(s)}">{e(s)}</a>' for s in tables) or "no study found"
    head = (f"<h1>arcsem report</h1><p>{n_runs} run(s) from {e(', '.join(sources))}; generated {when}. "
            f'All runs: <a href="all_runs.csv">all_runs.csv</a>.</p><p>{toc}</p>')
    body = [head]
    body += [_section(t, grids.get(s, []), videos.get(s, []), out) for s, t in tables.items()]
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>arcsem report</title>"
            f"<style>{STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    path = out / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
