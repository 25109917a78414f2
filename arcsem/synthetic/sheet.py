"""Contact sheet of a synthetic scene: all grey training views, then the five colour references."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

__all__ = ["contact_sheet"]


def _thumb(img: np.ndarray, width: int) -> Image.Image:
    im = Image.fromarray(img)
    if im.width > width:
        im = im.resize((width, round(im.height * width / im.width)), Image.Resampling.BOX)
    return im.convert("RGB")


def contact_sheet(greys: list[tuple[str, np.ndarray]], refs: list[tuple[str, np.ndarray]], path: Path,
                  cols: int = 8, thumb_width: int = 192, pad: int = 4) -> Path:
    """Write a PNG grid of grey views ``[(name, uint8 [H, W])]`` and one row of colour references
    ``[(name, uint8 [H, W, 3])]``, each labelled with its view name; returns ``path``."""
    tg = [(n, _thumb(a, thumb_width)) for n, a in greys]
    tr = [(n, _thumb(a, thumb_width)) for n, a in refs]
    w, h = tg[0][1].size
    rows = -(-len(tg) // cols) + (1 if tr else 0)
    ncol = max(cols, len(tr))
    sheet = Image.new("RGB", (ncol * (w + pad) + pad, rows * (h + pad) + pad + (12 if tr else 0)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for i, (name, im) in enumerate(tg):
        x, y = pad + (i % cols) * (w + pad), pad + (i // cols) * (h + pad)
        sheet.paste(im, (x, y))
        draw.text((x + 2, y + 1), name, fill=(255, 255, 0))
    y0 = pad + (rows - 1) * (h + pad) + 12
    if tr:
        draw.text((pad, y0 - 12), "colour references: " + ", ".join(n for n, _ in tr), fill=(255, 255, 255))
    for i, (name, im) in enumerate(tr):
        x = pad + i * (w + pad)
        sheet.paste(im, (x, y0))
        draw.text((x + 2, y0 + 1), name, fill=(255, 255, 255))
    sheet.save(path)
    return path
