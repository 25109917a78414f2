"""Training curves from ``train_history.csv`` (written by stage 1): loss and PSNR against step,
one line per run, drawn with OpenCV (no plotting library needed).

``training_curves(runs, path)`` reads ``<run>/train_history.csv`` (or ``<run>/stage1/...``, the shared
stage-1 model) of every run and writes one PNG with two panels, one curve a stage-1 model (rows sharing one are
named together); runs without a history are skipped.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["histories", "history_path", "training_curves"]

COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
           (227, 119, 194), (127, 127, 127)]  # RGB, one per run (drawn as BGR)
W, H, M = 420, 260, (52, 14, 22, 40)  # panel size; margins left, right, top, bottom


def history_path(run: Path) -> Path | None:
    """The run's stage-1 history file (its own, or the shared stage-1 model's), or None."""
    return next((c for c in (Path(run) / "train_history.csv", Path(run) / "stage1" / "train_history.csv")
                 if c.is_file()), None)


def _read(path: Path) -> pd.DataFrame | None:
    """A stage-1 history (``step``, ``loss``, ``psnr``, ...), or None without steps and losses."""
    df = pd.read_csv(path)
    return df if {"step", "loss"} <= set(df.columns) and len(df) else None


def _ticks(lo: float, hi: float, n: int = 4) -> list[float]:
    step = 10 ** np.floor(np.log10(max(hi - lo, 1e-12) / n))
    step *= next((m for m in (1, 2, 5, 10) if (hi - lo) / (step * m) <= n), 10)
    return list(np.arange(np.ceil(lo / step) * step, hi + 1e-9 * step, step))


def _panel(series: list[tuple[np.ndarray, np.ndarray]], title: str, log: bool) -> np.ndarray:
    import cv2

    img = np.full((H, W, 3), 255, np.uint8)
    x0, x1, y0, y1 = M[0], W - M[1], M[2], H - M[3]
    xs = np.concatenate([s[0] for s in series])
    ys = np.concatenate([s[1] for s in series])
    ys_t = np.log10(np.clip(ys, 1e-12, None)) if log else ys
    ok = np.isfinite(ys_t)
    xlo, xhi = float(xs.min()), float(xs.max()) if xs.max() > xs.min() else float(xs.min()) + 1
    ylo, yhi = (float(ys_t[ok].min()), float(ys_t[ok].max())) if ok.any() else (0.0, 1.0)
    yhi = yhi if yhi > ylo else ylo + 1
    px = lambda x: x0 + (x - xlo) / (xhi - xlo) * (x1 - x0)
    py = lambda y: y1 - (y - ylo) / (yhi - ylo) * (y1 - y0)
    font, black = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)
    for t in _ticks(ylo, yhi):
        y = int(py(t))
        cv2.line(img, (x0, y), (x1, y), (225, 225, 225), 1)
        cv2.putText(img, f"{10 ** t:.3g}" if log else f"{t:.3g}", (2, y + 4), font, 0.35, black, 1, cv2.LINE_AA)
    for t in _ticks(xlo, xhi):
        x = int(px(t))
        cv2.line(img, (x, y1), (x, y1 + 4), black, 1)
        cv2.putText(img, f"{t:.0f}", (x - 12, y1 + 16), font, 0.35, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (x0, y0), (x1, y1), black, 1)
    for k, (x, y) in enumerate(series):
        yt = np.log10(np.clip(y, 1e-12, None)) if log else y
        keep = np.isfinite(yt)
        pts = np.stack([px(x[keep]), py(yt[keep])], -1).round().astype(np.int32)
        cv2.polylines(img, [pts], False, COLOURS[k % len(COLOURS)][::-1], 2, cv2.LINE_AA)
    cv2.putText(img, title, (x0, y0 - 5), font, 0.42, black, 1, cv2.LINE_AA)
    cv2.putText(img, "step", (x1 - 30, H - 6), font, 0.38, black, 1, cv2.LINE_AA)
    return img


def _legend(labels: list[str], width: int) -> np.ndarray:
    import cv2

    img = np.full((20 * ((len(labels) + 2) // 3) + 6, width, 3), 255, np.uint8)
    for k, label in enumerate(labels):
        x, y = 10 + (k % 3) * (width // 3), 16 + 20 * (k // 3)
        cv2.line(img, (x, y - 4), (x + 22, y - 4), COLOURS[k % len(COLOURS)][::-1], 3)
        cv2.putText(img, label[:40], (x + 28, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def histories(runs: Mapping[str, Path]) -> dict[str, pd.DataFrame]:
    """Curve label -> history, one a stage-1 model: rows that share one (``share_stage1``: the default and the
    pseudo-colours of one scene and seed) give one curve, named by the first and how many more ("(+5 rows)")."""
    shared: dict[Path, list[str]] = {}
    for label, run in runs.items():
        if (p := history_path(Path(run))) is not None:
            shared.setdefault(p.resolve(), []).append(label)
    return {(labels[0] if len(labels) == 1 else f"{labels[0]} (+{len(labels) - 1} rows)"): h
            for p, labels in shared.items() if (h := _read(p)) is not None}


def training_curves(runs: Mapping[str, Path], path: Path) -> Path | None:
    """Write the loss and PSNR panels of every run with a history to ``path``; None if none has one."""
    import cv2

    hist = histories(runs)
    if not hist:
        return None
    mean = all("loss_mean" in h for h in hist.values())  # each log interval's mean (older runs: one batch's)
    key = "loss_mean" if mean else "loss"
    loss = [(h["step"].to_numpy(float), h[key].to_numpy(float)) for h in hist.values()]
    panels = [_panel(loss, f"training loss{', mean per log interval' if mean else ''} (log scale)", log=True)]
    if all("psnr" in h for h in hist.values()):
        psnr = [(h["step"].to_numpy(float), h["psnr"].to_numpy(float)) for h in hist.values()]
        panels.append(_panel(psnr, "PSNR of the training batch (dB)", log=False))
    body = np.concatenate(panels, 1)
    img = np.concatenate([body, _legend(list(hist), body.shape[1])], 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)  # drawn in BGR
    return path
