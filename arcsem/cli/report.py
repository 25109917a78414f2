"""``arcsem-report PATH... [--out DIR]``: tables, grids and an HTML page from run/multirun folders."""
from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="arcsem-report",
        description="Read every metrics.json under the given run or multirun folders and write a CSV, "
                    "Markdown and LaTeX table per study, image grids and index.html.")
    parser.add_argument("paths", nargs="+", metavar="PATH", help="run or multirun folder(s)")
    parser.add_argument("--out", default=None, help="output folder (default: PATH/report of the first PATH)")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    args = parser.parse_args(argv)

    from arcsem.cli.errors import call_reporting_errors
    from arcsem.report import build_report

    def report() -> int:
        print(f"report: {build_report(args.paths, args.out)}")
        return 0

    return call_reporting_errors(report, args.debug)


if __name__ == "__main__":
    sys.exit(main())
