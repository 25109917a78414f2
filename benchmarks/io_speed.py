"""Host work around the images of a run, before and after: the readers' grey-content check and the PNGs a run writes.

* grey check: ``max(-1) - min(-1)`` and ``mean(-1)`` (reductions over a 3-long axis, the readers before) against
  :func:`arcsem.data.io.grey_if_equal_channels` now (pairwise channel differences), on a colour and on a grey-content
  RGB image of ``--size`` px (the NeRF-synthetic 800x800: 300 views read 14.5 s in the check, py-spy);
* PNG writes: imageio's default zlib level (9) against :data:`arcsem.visual.PNG_LEVEL`, on the PNGs of ``--pngs``
  (e.g. a run's ``renders/test``; default: the built-in scene's views, generated if needed), with the bytes written.

Medians of ``--repeats``, milliseconds an image::

    .venv/bin/python benchmarks/io_speed.py [--pngs RUN/renders/test] [--size 800] [--repeats 5]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def _old_grey_check(img: np.ndarray) -> np.ndarray:
    spread = img.max(-1) - img.min(-1)
    if spread.any() and np.mean(spread > 4 / 255) <= 1e-3:
        return np.ascontiguousarray(np.repeat(img.mean(-1, keepdims=True), 3, axis=-1))
    return img


def grey_check(size: int, repeats: int) -> list[str]:
    from arcsem.data.io import grey_if_equal_channels

    rng = np.random.default_rng(0)
    colour = rng.random((size, size, 3), dtype=np.float32)
    grey = np.repeat(colour[..., :1], 3, -1) + rng.random((size, size, 3), dtype=np.float32) * 1e-3
    rows = []
    for name, img in (("colour", colour), ("grey content", grey)):
        assert np.array_equal(_old_grey_check(img), grey_if_equal_channels(img)[0])  # the same result
        old = _ms(lambda im=img: _old_grey_check(im), repeats)
        new = _ms(lambda im=img: grey_if_equal_channels(im), repeats)
        rows.append(f"| grey check, {name} {size}x{size} | {old:.1f} | {new:.1f} | {old / new:.1f}x |")
    return rows


def png_writes(folder: Path | None, repeats: int) -> list[str]:
    import imageio.v2 as imageio

    from arcsem.visual import PNG_LEVEL

    if folder is None:
        from arcsem.synthetic import ensure_scene

        scene = Path(ensure_scene())
        folder = (scene.parent if scene.is_file() else scene) / "color"
    imgs = [imageio.imread(p) for p in sorted(folder.glob("*.png"))[:40]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "x.png"
        res = {}
        for level in (9, PNG_LEVEL):
            size = 0
            for im in imgs:
                imageio.imwrite(out, im, compress_level=level)
                size += os.path.getsize(out)
            ms = _ms(lambda lv=level: [imageio.imwrite(out, im, compress_level=lv) for im in imgs], repeats)
            res[level] = (ms / len(imgs), size)
    (old, old_b), (new, new_b) = res[9], res[PNG_LEVEL]
    shape = "x".join(map(str, imgs[0].shape[:2][::-1]))
    rows.append(f"| PNG write, {len(imgs)} images of {shape} from {folder} (level 9 -> {PNG_LEVEL}) | {old:.1f} | "
                f"{new:.1f} | {old / new:.1f}x (bytes {new_b / old_b:.2f}x) |")
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pngs", type=Path, default=None)
    ap.add_argument("--size", type=int, default=800)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    print("| what | before (ms an image) | now | ratio |\n|---|---:|---:|---:|")
    print("\n".join(grey_check(args.size, args.repeats) + png_writes(args.pngs, args.repeats)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
