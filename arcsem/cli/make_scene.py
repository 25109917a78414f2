"""``arcsem-make-scene``: write the built-in synthetic SEM scene anywhere (default: the cache).

Example: ``arcsem-make-scene --out scenes/grain --seed 0 --width 288 --height 192 --camera pinhole``
"""
from __future__ import annotations

import argparse
import sys
import time

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from ..synthetic import SceneParams as P  # the defaults are the built-in scene's
    from ..synthetic.write import SPECIMENS

    ap = argparse.ArgumentParser(prog="arcsem-make-scene", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="scene folder (default: the cache, reused if complete)")
    ap.add_argument("--seed", type=int, default=P.seed)
    ap.add_argument("--width", type=int, default=P.width)
    ap.add_argument("--height", type=int, default=P.height)
    ap.add_argument("--camera", choices=("pinhole", "orthographic"), default=P.camera)
    ap.add_argument("--n-horizontal", type=int, default=P.n_horizontal, help="views on the horizontal arc")
    ap.add_argument("--n-vertical", type=int, default=P.n_vertical, help="views on the vertical arc")
    ap.add_argument("--no-substrate", action="store_true", help="render the grain without the substrate plane")
    ap.add_argument("--supersample", type=int, default=P.supersample, help="s x s samples on silhouette pixels (1 = off)")
    ap.add_argument("--noise", type=float, default=P.noise, help="Gaussian scan noise of the training images")
    ap.add_argument("--specimen", choices=SPECIMENS, default=P.specimen)
    ap.add_argument("--texture", type=float, default=P.texture,
                    help="surface texture amplitude on specimen and substrate (0 = none; 0.3 = SEM-like)")
    ap.add_argument("--force", action="store_true", help="with --out: regenerate even if the folder is complete")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from ..errors import ConfigError
    from ..synthetic import ensure_scene, generate_scene
    from .errors import call_reporting_errors

    params = {"seed": args.seed, "width": args.width, "height": args.height, "camera": args.camera,
                  "n_horizontal": args.n_horizontal, "n_vertical": args.n_vertical, "substrate": not args.no_substrate,
                  "supersample": args.supersample, "noise": args.noise,
              "specimen": args.specimen, "texture": args.texture}
    t0 = time.perf_counter()

    def make() -> int:
        if args.n_horizontal < 3 or args.n_vertical < 3 or args.supersample < 1 or not 0 <= args.texture < 1:
            raise ConfigError("--n-horizontal/--n-vertical must be >= 3, --supersample >= 1, 0 <= --texture < 1")
        if args.out is not None and args.force:
            path = generate_scene(args.out, **params)
            (path.parent / ".complete").write_text("{}")
        else:
            path = ensure_scene(args.out, **params)
        print(f"{path}  ({time.perf_counter() - t0:.1f} s)")
        return 0

    return call_reporting_errors(make, args.debug)


if __name__ == "__main__":
    sys.exit(main())
