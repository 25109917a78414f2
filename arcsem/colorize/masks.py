"""Specimen masks for stage 2: from files, from the dataset, or computed from the grey image.

Automatic masks (OpenCV): Otsu threshold, morphological open/close, largest connected component,
hole filling; or GrabCut initialised from that mask. Segment Anything is used only when the
``segment_anything`` package is importable and a checkpoint path is given.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError, DataError

__all__ = ["grabcut_mask", "load_mask_files", "otsu_mask", "sam_mask", "specimen_masks"]


def _to_u8(gray: np.ndarray | Tensor) -> np.ndarray:
    """``[H, W]`` or ``[H, W, 3]`` in [0, 1] -> ``[H, W]`` uint8."""
    g = torch.as_tensor(gray).float()
    if g.ndim == 3:
        g = g.mean(-1)
    return (g.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()


def otsu_mask(gray, kernel: int = 5, dark_background: bool = True) -> np.ndarray:
    """Automatic specimen mask of one grey image ``[H, W(, 3)]`` -> bool ``[H, W]``.

    Otsu threshold (specimen brighter than the background unless ``dark_background`` is False),
    morphological open then close with an elliptic ``kernel``, largest connected component, holes
    filled.
    """
    import cv2

    g = cv2.GaussianBlur(_to_u8(gray), (3, 3), 0)
    mode = cv2.THRESH_BINARY if dark_background else cv2.THRESH_BINARY_INV
    _, m = cv2.threshold(g, 0, 255, mode | cv2.THRESH_OTSU)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kernel, kernel))
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, k)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return np.zeros(m.shape, bool)
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    m = (lab == big).astype(np.uint8)
    return _fill_holes(m)


def _fill_holes(m: np.ndarray) -> np.ndarray:
    """Fill background regions not connected to the image border (``m`` uint8 {0,1})."""
    import cv2

    h, w = m.shape
    flood = np.pad(m, 1).copy()
    ff_mask = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(flood, ff_mask, (0, 0), 1)
    holes = flood[1:-1, 1:-1] == 0
    return (m > 0) | holes


def grabcut_mask(image, init: np.ndarray | None = None, iters: int = 5) -> np.ndarray:
    """GrabCut refinement ``[H, W(, 3)]`` -> bool ``[H, W]``, initialised from ``init`` (default Otsu)."""
    import cv2

    img = torch.as_tensor(image).float()
    if img.ndim == 2:
        img = img[..., None].expand(-1, -1, 3)
    u8 = (img.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy().copy()
    init = otsu_mask(image) if init is None else init.astype(bool)
    if init.sum() == 0 or init.all():
        return init
    gc = np.where(init, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    eroded = cv2.erode(init.astype(np.uint8), np.ones((7, 7), np.uint8), iterations=2) > 0
    dilated = cv2.dilate(init.astype(np.uint8), np.ones((7, 7), np.uint8), iterations=2) > 0
    gc[eroded] = cv2.GC_FGD
    gc[~dilated] = cv2.GC_BGD
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(u8, gc, None, bgd, fgd, iters, cv2.GC_INIT_WITH_MASK)
    return (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)


def sam_mask(images: Tensor, checkpoint: str, model_type: str = "vit_h") -> Tensor:
    """Segment Anything masks ``[N, H, W]`` of ``images [N, H, W, 3]`` (largest-area mask, centre-prompted)."""
    try:
        from segment_anything import SamPredictor, sam_model_registry  # type: ignore
    except ImportError:
        raise ConfigError("masks: source 'sam' needs the 'segment_anything' package (pip install segment-anything)") from None
    if not checkpoint or not Path(checkpoint).is_file():
        raise ConfigError(f"masks: source 'sam' needs a checkpoint file; '{checkpoint}' does not exist")
    predictor = SamPredictor(sam_model_registry[model_type](checkpoint=checkpoint))
    out = []
    for img in images:
        u8 = (img.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()
        predictor.set_image(u8)
        h, w = u8.shape[:2]
        masks, scores, _ = predictor.predict(point_coords=np.array([[w / 2, h / 2]]), point_labels=np.array([1]))
        out.append(torch.from_numpy(masks[int(np.argmax(scores))].astype(bool)))
    return torch.stack(out)


def load_mask_files(names: list[str], folder: str, hw: tuple[int, int]) -> Tensor:
    """Masks ``[N, H, W]`` bool read from ``folder/<name>.<ext>`` (non-zero = specimen)."""
    import imageio.v3 as iio

    out = []
    for n in names:
        cands = sorted(Path(folder).glob(f"{n}.*"))
        if not cands:
            raise DataError(f"masks: no mask file for view '{n}' in '{folder}'")
        arr = np.asarray(iio.imread(cands[0]))
        arr = arr[..., 0] if arr.ndim == 3 else arr
        if arr.shape != tuple(hw):
            raise DataError(f"mask '{cands[0]}': size {arr.shape[1]}x{arr.shape[0]} differs from view ({hw[1]}x{hw[0]})")
        out.append(torch.from_numpy(arr > 0))
    return torch.stack(out)


def specimen_masks(split, source: str = "auto", folder: str | None = None, sam_checkpoint: str | None = None) -> Tensor:
    """Masks ``[N, H, W]`` bool for a split.

    ``source``: ``"dataset"`` (``split.masks``), ``"files"`` (``folder``), ``"otsu"``, ``"grabcut"``,
    ``"sam"`` or ``"auto"`` (the dataset's masks where it has them, else Otsu) or ``"none"`` (all ones).
    """
    hw = (split.cameras.height, split.cameras.width)
    if source == "auto":
        source = "dataset" if split.masks is not None else "otsu"
    if source == "dataset":
        if split.masks is None:
            raise DataError("masks: source 'dataset' but the dataset has no masks; use 'otsu', 'grabcut' or 'files'")
        m = torch.as_tensor(split.masks)
        return (m[..., 0] if m.ndim == 4 else m).bool()
    if source == "files":
        if not folder:
            raise ConfigError("masks: source 'files' needs masks.folder")
        return load_mask_files(split.names, folder, hw)
    if source == "otsu":
        return torch.stack([torch.from_numpy(otsu_mask(im)) for im in split.images])
    if source == "grabcut":
        return torch.stack([torch.from_numpy(grabcut_mask(im)) for im in split.images])
    if source == "sam":
        return sam_mask(split.images, sam_checkpoint or "")
    if source == "none":
        return torch.ones(len(split), *hw, dtype=torch.bool)
    raise ConfigError(f"masks: unknown source '{source}'; use auto|dataset|files|otsu|grabcut|sam|none")
