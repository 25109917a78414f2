"""``arcsem-view RUN [--port 8080]``: look around a trained model in the browser (http://HOST:PORT).

Renders with arcsem's CPU rasteriser: previews at an adaptive resolution while the camera moves,
full resolution when it stops; grey / colour / depth / normal; pinhole or orthographic; the
training cameras as frusta. Ctrl-C stops it.
"""
from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="arcsem-view", description=__doc__.splitlines()[0])
    parser.add_argument("run", metavar="RUN", help="a run folder written by arcsem (with checkpoints/)")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8080)
    parser.add_argument("--max-height", type=int, default=1024, help="height cap of full-resolution frames")
    parser.add_argument("--no-frusta", action="store_true", help="do not draw the training cameras")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    args = parser.parse_args(argv)

    from arcsem.cli.errors import call_reporting_errors

    def serve() -> int:
        import time

        from arcsem.viewer import Viewer, ViewerConfig

        viewer = Viewer(args.run, ViewerConfig(args.host, args.port, args.max_height, frusta=not args.no_frusta))
        viewer.start()
        print(f"arcsem-view: open http://{args.host}:{args.port} (Ctrl-C stops)", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            viewer.stop()
        return 0

    return call_reporting_errors(serve, args.debug)


if __name__ == "__main__":
    sys.exit(main())
