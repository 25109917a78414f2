"""One static HTML page: per study the table, its notes, links to CSV/Markdown/LaTeX, grids, training
curves, videos and the runs' files (models, meshes, viewer folders, CSVs).

Every link is relative to the page. Videos are copied next to it (``videos/<study>/...``); the runs'
larger files (PLY, meshes) are linked where they are, so those links hold while the report stays
beside the runs (``<run>/report`` for a single run). The page names no machine path. A small script
checks, when the page loads, that every image loaded and every table has rows, and lists what did
not at the top of the page (``data-check`` on ``<body>``: ``ok`` or ``broken``).
"""
from __future__ import annotations

import html
import os
import shutil
from datetime import datetime, timezone
from pathlib import Path

from .tables import ROW_HEADER, Table

__all__ = ["copy_videos", "files_table", "render_table", "write_page"]

STYLE = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}th,td{padding:3px 8px;border-bottom:1px solid #ccc}
td{text-align:right}td:first-child,th:first-child{text-align:left}th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd}figure{display:inline-block;margin:4px}video{max-width:380px}.notes{font-size:90%;color:#444}
.broken{background:#fdd;border:1px solid #c00;padding:6px}code{background:#f3f3f3;padding:0 3px}
table.files{table-layout:fixed;width:100%;font-size:85%}table.files td,table.files th{overflow-wrap:anywhere;text-align:left}
table.metrics{font-size:85%}table.metrics th,table.metrics td{padding:3px 4px}table.metrics td.text{text-align:left;min-width:5em;max-width:10em;overflow-wrap:anywhere}"""

CHECK = """<script>
window.addEventListener('load', function () {
  var bad = [];
  document.querySelectorAll('img').forEach(function (i) {
    if (!i.complete || i.naturalWidth === 0) bad.push('image not found: ' + i.getAttribute('src'));
  });
  document.querySelectorAll('table').forEach(function (t) {
    if (t.querySelectorAll('td').length === 0) bad.push('empty table: ' + (t.id || 'unnamed'));
    if (t.getBoundingClientRect().right > document.documentElement.clientWidth + 1)
      bad.push('table wider than the window: ' + (t.className || t.id || 'unnamed'));
  });
  document.body.dataset.check = bad.length ? 'broken' : 'ok';
  if (bad.length) {
    var box = document.createElement('div'); box.className = 'broken'; box.id = 'check';
    box.textContent = 'This page is incomplete: ' + bad.join('; ');
    document.body.insertBefore(box, document.body.firstChild);
  }
});
</script>"""

RUN_FILES = (  # (column, candidate paths inside a run folder, first found wins)
    ("model", ("model.ply", "model.npz", "stage1/model.ply", "stage1/model.npz")),
    ("mesh", ("mesh.ply", "stage1/mesh.ply")), ("mesh GLB", ("mesh.glb", "stage1/mesh.glb")),
    ("viewer folder", ("viewer/cameras.json", "stage1/viewer/cameras.json")),
    ("coloured model", ("colored_model.ply", "colored_model.npz")),
    ("coloured mesh", ("colored_mesh.ply",)), ("coloured GLB", ("colored_mesh.glb",)),
    ("coloured viewer", ("colored_viewer/cameras.json",)),
    ("views CSV", ("views.csv", "stage1/views.csv")), ("colour views CSV", ("colorize/views.csv",)),
    ("history CSV", ("train_history.csv", "stage1/train_history.csv")), ("metrics", ("metrics.json",)),
)


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
    cls = ['' if not c.text else ' class="text"' for c in t.columns]
    body = "".join("<tr><td>" + e(label) + "</td>" + "".join(
        f"<td{k}><b>{e(x)}</b></td>" if b else f"<td{k}>{e(x)}</td>" for k, (x, b) in zip(cls, row)) + "</tr>"
        for label, row in zip(t.labels, t.cells))
    return f'<table class="metrics">{top}{head}{body}</table>'


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
            _poster(dst)
            found.append((f"{label}: {mp4.stem}", dst))
    return found


def _poster(mp4: Path) -> Path | None:
    """``<video>.jpg``: the video's middle frame, shown before it plays (a browser shows black without one);
    None when the file cannot be decoded."""
    import cv2

    cap = cv2.VideoCapture(str(mp4))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    if n > 1:
        cap.set(cv2.CAP_PROP_POS_FRAMES, n // 2)
    ok, frame = cap.read()
    cap.release()
    if not ok or frame is None:
        return None
    out = mp4.with_suffix(".jpg")
    return out if cv2.imwrite(str(out), frame) else None


def files_table(runs: dict[str, Path], out: Path) -> str:
    """``<table>`` of the runs' files (one row per run, a link per kind of file that exists)."""
    e = html.escape
    rows, cols = [], [c for c, _ in RUN_FILES]
    used = set()
    for label, run in runs.items():
        cells = []
        for col, cands in RUN_FILES:
            found = next((Path(run) / c for c in cands if (Path(run) / c).exists()), None)
            if found is None:
                cells.append("<td></td>")
                continue
            used.add(col)
            target = found.parent if found.name == "cameras.json" else found
            href = Path(os.path.relpath(target, out)).as_posix() + ("/" if target.is_dir() else "")
            shown = target.relative_to(run).as_posix()  # colorize/views.csv, not a second "views.csv"
            cells.append(f'<td><a href="{e(href)}">{e(shown)}</a></td>')
        rows.append((label, cells))
    keep = [i for i, c in enumerate(cols) if c in used]
    if not keep:
        return ""
    head = "<tr><th>Run</th>" + "".join(f"<th>{e(cols[i])}</th>" for i in keep) + "</tr>"
    body = "".join(f"<tr><td>{e(label)}</td>" + "".join(cells[i] for i in keep) + "</tr>" for label, cells in rows)
    return f'<table class="files">{head}{body}</table>'


def _section(t: Table, grids: list[tuple[str, Path]], videos: list[tuple[str, Path]], out: Path,
             curves: Path | None = None, files: str = "") -> str:
    e = html.escape
    rel = lambda p: e(Path(p).relative_to(out).as_posix())
    links = " · ".join(f'<a href="{e(t.study)}.{ext}">{ext.upper()}</a>' for ext in ("csv", "md", "tex"))
    parts = [f'<h2 id="{e(t.study)}">{e(t.study.replace("_", " "))}</h2>', render_table(t),
             '<ol class="notes">' + "".join(f"<li>{e(n)}</li>" for n in t.notes) + "</ol>",
             f"<p>Download: {links}</p>"]
    for title, png in grids:
        parts.append(f"<h3>{e(title)}</h3><p><img src=\"{rel(png)}\" alt=\"{e(title)}\"></p>")
    if curves is not None:
        parts.append(f'<h3>training curves (stage 1)</h3><p><img src="{rel(curves)}" alt="training curves"></p>')
    if videos:
        parts.append("<h3>videos</h3><div>" + "".join(
            f'<figure><video controls muted loop preload="metadata" src="{rel(v)}"'
            + (f' poster="{rel(v.with_suffix(".jpg"))}"' if v.with_suffix(".jpg").is_file() else "")
            + f'></video><figcaption>{e(c)}</figcaption></figure>' for c, v in videos) + "</div>")
    if files:
        parts.append("<h3>files</h3><p class=\"notes\">Models (PLY), meshes (PLY for Blender/MeshLab, GLB for "
                     "web viewers), viewer folders (open in a 3DGS viewer, or <code>arcsem-view RUN</code>), "
                     "per-view metrics and training histories (CSV):</p>" + files)
    return "\n".join(parts)


def write_page(out: Path, tables: dict[str, Table], grids: dict[str, list[tuple[str, Path]]],
               videos: dict[str, list[tuple[str, Path]]], sources: list[str], n_runs: int,
               curves: dict[str, Path | None] | None = None, files: dict[str, str] | None = None) -> Path:
    """Write ``out/index.html`` and return its path (``sources`` are shown by folder name only)."""
    e = html.escape
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    toc = " · ".join(f'<a href="#{e(s)}">{e(s)}</a>' for s in tables) or "no study found"
    names = ", ".join(Path(s).resolve().name for s in sources)
    head = (f"<h1>arcsem report</h1><p>{n_runs} run(s) from {e(names)}; generated {when}. "
            f'All runs: <a href="all_runs.csv">all_runs.csv</a>.</p><p>{toc}</p>')
    body = [head]
    body += [_section(t, grids.get(s, []), videos.get(s, []), out, (curves or {}).get(s), (files or {}).get(s, ""))
             for s, t in tables.items()]
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>arcsem report</title>"
            f"<style>{STYLE}</style>{CHECK}</head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    path = out / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
