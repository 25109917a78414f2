"""Image grids (numpy + OpenCV): ground truth beside each row's render of the same view.

Files read from a run folder (names as the trainer and the colouriser write them):

- ``renders/test/<view>.png``        stage-1 render of a held-out view (``renders/train/`` if none)
- ``renders/test/<view>_depth.png``  its depth visualisation (turbo, below the nearest GT point,
  masked like the ground truth; the colour bar's scale comes from ``metrics.json``)
- ``renders/test/<view>_gt.png``     ground-truth grey image (optional; else the dataset folder)
- ``renders/test/<view>_depth_gt.png`` ground-truth depth visualisation (optional)
- ``colorize/renders/test/<view>.png`` stage-2 coloured held-out view (``_gt.png`` beside it: its true colour)
- ``colored/<view>.png``             stage-2 coloured training view (where a run has no held-out view)
- ``colored/<view>_gt.png``          ground-truth colour (optional; else the dataset folder)

Ground truth found in neither is rendered from the run's dataset (``config.yaml`` ``dataset``).

Where a file is missing, the tile says "missing" instead of failing.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import yaml

from .groundtruth import GroundTruth

__all__ = ["TILE_H", "gt_path", "make_grid", "placeholder", "read_image", "study_grids", "tile_label", "view_names"]

TILE_H = 160          # tile height in pixels
LABEL_H = 22          # height of the label band above each tile
MAX_VIEWS = 3         # views shown per grid
SUFFIXES = ("_depth", "_gt", "_depth_gt", "_normal", "_alpha")


def read_image(path: Path | None) -> np.ndarray | None:
    """``[H, W, 3]`` uint8 BGR image, or None if ``path`` is None/missing/unreadable."""
    import cv2

    if path is None or not Path(path).is_file():
        return None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.dtype != np.uint8:  # 16-bit depth PNGs: stretch to 8 bits
        f = img.astype(np.float64)
        img = ((f - f.min()) / max(f.max() - f.min(), 1e-12) * 255).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def placeholder(h: int, w: int, text: str = "missing") -> np.ndarray:
    """``[h, w, 3]`` grey tile with ``text`` centred."""
    import cv2

    tile = np.full((h, w, 3), 200, np.uint8)
    cv2.rectangle(tile, (0, 0), (w - 1, h - 1), (120, 120, 120), 1)
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    cv2.putText(tile, text, ((w - tw) // 2, (h + th) // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 60, 60), 1,
                cv2.LINE_AA)
    return tile


def _fit(img: np.ndarray | None, h: int, w: int) -> np.ndarray:
    import cv2

    return placeholder(h, w) if img is None else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def _band(text: str, w: int) -> np.ndarray:
    import cv2

    band = np.full((LABEL_H, w, 3), 255, np.uint8)
    cv2.putText(band, text[: max(1, w // 8)], (4, LABEL_H - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    return band


def make_grid(paths: list[list[Path | None]], col_labels: list[str], row_labels: list[str] | None = None,
              tile_h: int = TILE_H) -> np.ndarray:
    """``[R, C]`` image paths -> one uint8 BGR image; labels above columns and left of rows.

    Every tile gets the aspect ratio of the first readable image (4:3 if none is readable).
    """
    imgs = [[read_image(p) for p in row] for row in paths]
    first = next((i for row in imgs for i in row if i is not None), None)
    w = round(tile_h * (4 / 3 if first is None else first.shape[1] / first.shape[0]))
    rows = [np.concatenate([np.concatenate([_band(lbl, w), _fit(i, tile_h, w)], 0)
                            for i, lbl in zip(row, col_labels)], 1) for row in imgs]
    if row_labels:
        rows = [np.concatenate([_side(lbl, r.shape[0]), r], 1) for lbl, r in zip(row_labels, rows)]
    return np.concatenate(rows, 0)


def _side(text: str, h: int, w: int = 90) -> np.ndarray:
    import cv2

    band = np.full((h, w, 3), 255, np.uint8)
    lines = [t if i == 0 else f"({t}" for i, t in enumerate(text.split(" ("))]  # "h_10 (reference)": two lines
    for k, line in enumerate(lines):
        y = h // 2 + 5 + 18 * (k - (len(lines) - 1) / 2)
        cv2.putText(band, line[:12], (4, int(y)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return band


def view_names(folder: Path, limit: int = MAX_VIEWS) -> list[str]:
    """Up to ``limit`` view names with a ``<name>.png`` in ``folder`` (suffixed variants skipped)."""
    if not folder.is_dir():
        return []
    names = sorted(p.stem for p in folder.glob("*.png") if not p.stem.endswith(SUFFIXES))
    if len(names) <= limit:
        return names
    idx = np.linspace(0, len(names) - 1, limit).round().astype(int)
    return [names[i] for i in idx]


def _dataset_config(run: Path) -> dict:
    """The run's ``dataset`` config (``config.yaml``), ``{}`` when it has none."""
    try:
        ds = (yaml.safe_load((run / "config.yaml").read_text()) or {}).get("dataset") or {}
    except (FileNotFoundError, yaml.YAMLError):
        return {}
    return ds if isinstance(ds, dict) else {"name": str(ds)}


def _dataset_root(run: Path, ds: dict | None = None) -> Path | None:
    ds = _dataset_config(run) if ds is None else ds
    root = next((ds.get(k) for k in ("root", "path", "dir") if isinstance(ds.get(k), str)), None)
    return None if root is None else Path(root).expanduser()


def gt_path(run: Path, name: str, kind: str, gt: GroundTruth | None = None,
            folder: str = "renders/test") -> Path | None:
    """Ground truth of view ``name`` (``kind``: gray | depth | color): a file in the run (next to the
    renders in ``folder``) or in the dataset folder, else a tile ``gt`` renders from the run's dataset."""
    local = {"gray": [f"{folder}/{name}_gt.png"], "depth": [f"{folder}/{name}_depth_gt.png"],
             "color": [f"{folder}/{name}_gt.png", f"colored/{name}_gt.png", f"colored_gt/{name}.png"]}[kind]
    cands = [run / p for p in local]
    root = _dataset_root(run)
    if root is not None:
        sub = {"gray": ["test", "images", "."], "depth": ["depth", "depths"], "color": ["colors", "color"]}[kind]
        cands += [root / s / f"{name}.png" for s in sub]
    found = next((c for c in cands if c.is_file()), None)
    return found if found is not None or gt is None else gt.tile(run, name, kind)


def _write(img: np.ndarray, path: Path) -> Path:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)
    return path


KINDS = {"grayscale_comparison": ("gray", "depth"), "colorization_ablation": ("color",), "colorization_benchmark": ("color",),
         "reference_count": ("color",), "feature_comparison": ("color",)}
"""Grid kinds per study; any other study (``runs``) gets every kind that has files."""
STAGE1_RENDERS = ("renders/test", "stage1/renders/test", "renders/train", "stage1/renders/train")
"""Where a run keeps its stage-1 renders: its own folder, or ``stage1/`` (``share_stage1``: a link to the
shared model's folder)."""
GRID = {  # kind -> (run folders, first with files wins; file suffix; ground-truth kind; first column; title)
    "gray": (STAGE1_RENDERS, "", "gray", "ground truth", "renders"),
    "depth": (STAGE1_RENDERS, "_depth", "depth", "GT depth", "depth maps"),
    "color": (("colorize/renders/test", "colored"), "", "color", "GT colour", "coloured views"),
}


def _pick(dirs: list[Path], folders: tuple[str, ...], suffix: str) -> tuple[str, list[str]]:
    """The first folder (and its view names) in which some run has ``<name><suffix>.png`` files."""
    for folder in folders:
        names = next((n for d in dirs if (n := view_names(d / folder))), [])
        if any((d / folder / f"{n}{suffix}.png").is_file() for d in dirs for n in names):
            return folder, names
    return folders[0], []


def depth_scale(run: Path) -> tuple[float, str] | None:
    """``(span, unit)`` of the run's depth images (:func:`arcsem.visual.depth_display`:
    ``0 .. span`` below the nearest ground-truth point): micrometres where the dataset gives a pixel
    size, else scene units; None when the run did not record it."""
    import json

    try:
        depth = ((json.loads((Path(run) / "metrics.json").read_text()).get("stage1") or {}).get("depth") or {})
    except (FileNotFoundError, ValueError):
        return None
    span = depth.get("display_span")
    if not isinstance(span, (int, float)):
        return None
    um = depth.get("micrometres_per_unit")
    return (span * um, "micrometres") if isinstance(um, (int, float)) and um > 0 else (span, "scene units")


def _depth_bar(runs: list[Path], out: Path, study: str) -> Path | None:
    """The colour bar under a depth grid (its first run's scale), or None."""
    from ..visual import colour_bar

    scale = next((s for r in runs if (s := depth_scale(r)) is not None), None)
    if scale is None:
        return None
    bar = colour_bar(0.0, scale[0], scale[1], width=420, label="depth below the nearest ground-truth point")
    return _write(bar[..., ::-1].copy(), out / f"{study}_depth_bar.png")


def _marked(names: list[str], run: Path) -> list[str]:
    """View names with `` (reference)`` after the run's stage-2 references (``metrics.json``)."""
    import json

    try:
        refs = set((json.loads((Path(run) / "metrics.json").read_text()).get("stage2") or {}).get("references") or [])
    except (FileNotFoundError, ValueError):
        refs = set()
    return [f"{n} (reference)" if n in refs else n for n in names]


def _dataset(run: Path) -> tuple[str, str]:
    """``(key, name)`` of the run's dataset (``config.yaml``): runs with equal keys show the same views."""
    import json

    ds = _dataset_config(run)
    root = _dataset_root(run, ds)
    name = ds.get("specimen") or (root.name if root else None) or ds.get("name") or ds.get("kind") or "dataset"
    return json.dumps(ds, sort_keys=True, default=str), str(name)


def study_grids(study: str, runs: Mapping[str, Path], out: Path,
                gt: GroundTruth | None = None) -> list[tuple[str, Path]]:
    """Grids of one study: ``runs`` maps row label -> one run folder. Returns ``[(title, png)]``.

    Held-out renders are shown where the runs have them, else training-view renders. Ground truth
    missing from the runs is rendered from the dataset by ``gt`` (default: tiles in ``out/gt``). Runs on
    several datasets (``colorization_benchmark``'s scenes) get a grid per dataset, each with its own views.
    """
    gt = gt if gt is not None else GroundTruth(out / "gt")
    groups: dict[str, tuple[str, dict[str, Path]]] = {}
    for label, d in runs.items():
        key, name = _dataset(Path(d))
        groups.setdefault(key, (name, {}))[1][label] = Path(d)
    if len(groups) == 1:
        return _grids(study, next(iter(groups.values()))[1], out, gt, "", "")
    return [g for k, (name, sub) in enumerate(groups.values())
            for g in _grids(study, _short(sub), out, gt, f", {name}", f"_{k}")]


def _short(runs: Mapping[str, Path]) -> dict[str, Path]:
    """The labels without the part all of them share first ("chair (held out), 1, default" -> "1, default")."""
    heads = {label.split(", ", 1)[0] for label in runs}
    if len(heads) != 1 or not all(", " in label for label in runs):
        return dict(runs)
    return {label.split(", ", 1)[1]: d for label, d in runs.items()}


def tile_label(label: str) -> str:
    """A column label short enough for a tile: a list in it (references given as files or view names,
    ``[refs/train/r_0.png,train/r_50]``) as its items' names (``r_0+r_50``); the rest as it is."""
    return re.sub(r"\[([^\]]*)\]", lambda m: "+".join(Path(x.strip()).stem or x.strip() for x in m.group(1).split(",")),
                  label)


def _grids(study: str, runs: Mapping[str, Path], out: Path, gt: GroundTruth, title_end: str,
           file_end: str) -> list[tuple[str, Path]]:
    """:func:`study_grids` of runs on one dataset (``title_end``, ``file_end``: what tells its grids apart)."""
    labels, dirs = [tile_label(k) for k in runs], [Path(d) for d in runs.values()]
    grids = []
    for kind in KINDS.get(study, ("gray", "depth", "color")):
        folders, suffix, gt_kind, gt_label, title = GRID[kind]
        folder, names = _pick(dirs, folders, suffix)
        if not names:
            continue
        paths = [[gt_path(dirs[0], n, gt_kind, gt, folder)] + [d / folder / f"{n}{suffix}.png" for d in dirs]
                 for n in names]
        img = make_grid(paths, [gt_label, *labels], _marked(names, dirs[0]) if folder == "colored" else names)
        where = " (held-out views)" if folder.endswith("renders/test") else (
            " (training views)" if folder.endswith("renders/train") else "")
        grids.append((f"{study}: {title}{where}{title_end}", _write(img, out / f"{study}_{kind}{file_end}.png")))
        bar = _depth_bar(dirs, out, f"{study}{file_end}") if kind == "depth" else None
        if bar is not None:
            grids.append((f"{study}: depth colour scale (both columns show the ground truth's pixels)", bar))
    return grids
