"""The report's table of run files: one link per kind of file, named by its path in the run folder."""
from __future__ import annotations

from arcsem.report.html import files_table


def test_links_name_their_path_in_the_run(tmp_path):
    run = tmp_path / "run"
    (run / "colorize").mkdir(parents=True)
    (run / "viewer").mkdir()
    for f in ("views.csv", "colorize/views.csv", "metrics.json", "viewer/cameras.json"):
        (run / f).write_text("x")
    html = files_table({"full": run}, tmp_path / "report")
    assert '<a href="../run/views.csv">views.csv</a>' in html
    assert '<a href="../run/colorize/views.csv">colorize/views.csv</a>' in html
    assert '<a href="../run/viewer/">viewer</a>' in html and "metrics.json" in html
    head = html.split("</tr>", 1)[0]
    assert "<th>views CSV</th>" in head and "<th>colour views CSV</th>" in head
    assert "mesh" not in head                                     # absent kinds get no column
