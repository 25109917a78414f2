"""One crop for a whole SEM series: the information banner (data bar) at the bottom and dead border lines.

A data bar is a block of rows at the bottom whose pixels are nearly all one grey level (white or black
ground, thin text and lines), under image rows that are not: per row, the *flatness* is the share of
pixels within one grey level of the row's most common value. The bar is the tallest bottom block
(1.5 % to 35 % of the height) whose mean flatness is >= 0.75, whose top row is flat (>= 0.6) and whose
16 rows above it are not (mean < 0.5). Where the metadata says how many rows the image has above its bar
(FEI ``ResolutionY``), that is used instead.

Dead lines are judged by their statistics relative to the image, not by fixed grey levels. Per side, with
``L_0`` the outermost line: a line is *odd* when it is flat (standard deviation under a tenth of the image's
median line deviation: a black row of small noise) or *unlike its inner neighbour* (mean absolute difference
``|L_k - L_k+1|`` over 4x the image's median such step, at least half a grey level: a corrupted or wrapped
column). The dead lines are the leading run of odd lines up to its last such jump, within 10 % of the size: a
flat band that fades into the content has no jump and stays (flat content, not a border).

The series gets one crop. The data bar: the median over the images (a bar that half of the images show is cut
from all of them). Dead lines per side: the count that a third of the images reach (a column corrupted in 3 of
7 frames is cut from all; a line costs little, a stray one left shows in every render). Every view keeps the
same size and pixel grid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Crop", "bar_height", "dead_lines", "dead_run", "detect_crop", "row_flatness"]

BAR_RANGE = (0.015, 0.35)
DEAD_MAX = 0.10
FLAT, JUMP = 0.1, 4.0  # odd lines: deviation under FLAT x, or step to the inner neighbour over JUMP x, the median


@dataclass(frozen=True)
class Crop:
    """Rows/columns removed from each side, and why (for the inspection table)."""

    top: int = 0
    bottom: int = 0
    left: int = 0
    right: int = 0
    reasons: tuple[str, ...] = ()

    def apply(self, arr: np.ndarray) -> np.ndarray:
        """``[H, W, ...]`` -> ``[H - top - bottom, W - left - right, ...]``."""
        return arr[self.top: arr.shape[0] - self.bottom, self.left: arr.shape[1] - self.right]

    def size(self, w: int, h: int) -> tuple[int, int]:
        """The cropped ``(w, h)`` of a ``w x h`` image."""
        return w - self.left - self.right, h - self.top - self.bottom

    def describe(self) -> str:
        sides = [f"{k} {v}" for k, v in (("top", self.top), ("bottom", self.bottom), ("left", self.left),
                                          ("right", self.right)) if v]
        return (", ".join(sides) or "none") + (f" ({'; '.join(self.reasons)})" if self.reasons else "")


def to_u8(pixels: np.ndarray) -> np.ndarray:
    """uint8 as is; uint16 scaled by its maximum to ``0..255``."""
    if pixels.dtype == np.uint8:
        return pixels
    top = max(int(pixels.max()), 1)
    return np.round(pixels.astype(np.float32) * (255.0 / top)).astype(np.uint8)


def row_flatness(img8: np.ndarray) -> np.ndarray:
    """``[H]`` share of each row's pixels within one grey level of the row's mode (``img8 [H, W]`` uint8)."""
    H, W = img8.shape
    idx = (np.arange(H, dtype=np.int64)[:, None] * 258 + img8.astype(np.int64) + 1).ravel()
    counts = np.bincount(idx, minlength=H * 258).reshape(H, 258)
    window = counts[:, :-2] + counts[:, 1:-1] + counts[:, 2:]
    return window.max(1) / float(W)


def bar_height(img8: np.ndarray, context: int = 16) -> int:
    """Rows of the data bar at the bottom of ``img8 [H, W]`` (0 without one; see the module docstring)."""
    flat = row_flatness(img8)[::-1]  # from the bottom row up
    H = len(flat)
    mean_from_bottom = np.cumsum(flat) / np.arange(1, H + 1)
    lo, hi = max(4, int(np.ceil(BAR_RANGE[0] * H))), int(BAR_RANGE[1] * H)
    for k in range(min(hi, H - context - 1), lo - 1, -1):
        if mean_from_bottom[k - 1] >= 0.75 and flat[k - 1] >= 0.6 and flat[k: k + context].mean() < 0.5:
            return k
    return 0


def dead_run(lines: np.ndarray, limit: int) -> int:
    """Dead outer lines of ``lines [N, M]`` float32 (line 0 outermost), at most ``limit``; module docstring."""
    std = lines.std(axis=1)                                   # [N]
    step = np.abs(np.diff(lines, axis=0)).mean(axis=1)        # [N - 1]: |L_k - L_k+1|
    jump = step[:limit] > JUMP * max(float(np.median(step)), 0.5)
    odd = (std[:limit] < FLAT * float(np.median(std))) | jump
    run = limit if odd.all() else int(np.argmin(odd))
    last = np.nonzero(jump[:run])[0]
    return int(last[-1]) + 1 if len(last) else 0


def dead_lines(img8: np.ndarray) -> dict[str, int]:
    """Dead border rows/columns per side of ``img8 [H, W]``: ``{top, bottom, left, right}`` (:func:`dead_run`)."""
    img = img8.astype(np.float32)
    return {side: dead_run(lines, int(DEAD_MAX * len(lines)))
            for side, lines in (("top", img), ("bottom", img[::-1]), ("left", img.T), ("right", img.T[::-1]))}


def detect_crop(images: list[np.ndarray], image_rows: list[int | None] | None = None,
                bottom: int | None = None) -> Crop:
    """One :class:`Crop` for ``images`` (``[H, W]`` uint8/uint16, one size); see the module docstring.

    ``image_rows``: per image the rows above its data bar from the metadata (None where unknown);
    ``bottom``: rows to cut at the bottom, given by the user (overrides the detection of the bar).
    """
    small = [to_u8(im) for im in images]
    H = images[0].shape[0]
    reasons = []
    if bottom is not None:
        bar, why = int(bottom), "bottom rows given by the user"
    else:
        hints = [H - r for r in (image_rows or []) if r is not None and 0 < r < H]
        if hints:
            bar, why = int(np.median(hints)), "data bar (rows from the metadata)"
        else:
            bar, why = int(np.median([bar_height(im) for im in small])), "data bar"
    if bar:
        reasons.append(f"{why}: {bar} rows")
    dead = [dead_lines(im[: H - bar]) for im in small]
    third = max(1, int(np.ceil(len(dead) / 3)))  # the count reached by a third of the images
    sides = {s: sorted((d[s] for d in dead), reverse=True)[third - 1] for s in ("top", "bottom", "left", "right")}
    if any(sides.values()):
        reasons.append("dead border lines")
    return Crop(top=sides["top"], bottom=bar + sides["bottom"], left=sides["left"], right=sides["right"],
                reasons=tuple(reasons))
