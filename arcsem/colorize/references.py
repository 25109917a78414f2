"""Artist colour references: matched to training views by name, validated at the boundary.

References come either from image files (the file stem names the training view, e.g.
``r_013.png`` colours view ``r_013``; where views are named with their folder, ``train/r_0``, so is the file:
``.../train/r_0.png``) or from a preset of the scene (``five``, ``four``, ``three``,
``two``, ``one``: the paper's reference sets, ``scene.reference_sets``) whose images are
``scene.references``. Every reference is checked: its size must equal the view's, its name must be a
training view, and its content must be a colour image (not empty, not grey).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..data.io import IMAGE_EXTS
from ..errors import ConfigError, DataError

__all__ = ["PRESETS", "References", "check_reference", "load_references"]

PRESETS = ("five", "four", "three", "two", "one")

# A reference whose channels differ by less than this everywhere is grey (no colour to propagate).
GREY_TOL = 2.0 / 255.0


@dataclass
class References:
    """``R`` colour references.

    Attributes:
        names: ``R`` training-view names.
        indices: ``[R]`` long, index of each reference in the training split.
        images: ``[R, H, W, 3]`` float32 colour images in [0, 1].
    """

    names: list[str]
    indices: Tensor
    images: Tensor

    def __len__(self) -> int:
        return len(self.names)


def _read_image(path: Path) -> Tensor:
    """``[H, W, 3]`` float32 in [0, 1], read as the dataset readers read a view (:func:`arcsem.data.io.read_image`:
    grey as three channels, RGBA over black; an alpha of 0 everywhere is ignored)."""
    from ..data.io import read_image

    try:
        img, alpha = read_image(path)
    except DataError as exc:
        raise DataError(f"reference {exc}") from None
    if alpha is not None and alpha.any():
        img = img * alpha[..., None]
    return torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32))


def _resize(image: Tensor, hw: tuple[int, int]) -> Tensor:
    """``[h, w, 3]`` -> ``[H, W, 3]`` by area resampling (as ``dataset.downscale`` shrinks the views)."""
    import cv2

    return torch.from_numpy(cv2.resize(image.numpy(), (hw[1], hw[0]), interpolation=cv2.INTER_AREA))


def check_reference(name: str, image: Tensor, view_hw: tuple[int, int], where: str) -> Tensor:
    """Validate one reference ``image [H, W, 3]`` against its view's size; returns float32 [H, W, 3], resized to
    the view where it is the view at another scale (a full-size reference of a run with ``dataset.downscale``).

    Raises DataError naming ``where`` (file or view) when the size differs otherwise, the image is empty
    (one constant value) or grey (channels equal).
    """
    image = torch.as_tensor(image, dtype=torch.float32)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise DataError(f"reference {where}: expected an [H, W, 3] colour image, got shape {tuple(image.shape)}")
    if tuple(image.shape[:2]) != tuple(view_hw):
        h, w = image.shape[:2]
        if abs(h * view_hw[1] / w - view_hw[0]) > 1.0:  # not the view at another scale (dataset.downscale)
            raise DataError(f"reference {where}: size {w}x{h} differs from view '{name}' ({view_hw[1]}x{view_hw[0]}) "
                            "and is not the view at another scale")
        image = _resize(image, view_hw)
    if float(image.max() - image.min()) < GREY_TOL:
        raise DataError(f"reference {where}: image is empty (a single value)")
    spread = (image.max(-1).values - image.min(-1).values).max()
    if float(spread) < GREY_TOL:
        raise DataError(f"reference {where}: image is grey (no colour); colour it before use")
    return image


def _view_index(names: list[str], name: str, where: str) -> int:
    if name not in names:
        shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
        raise DataError(f"reference {where}: '{name}' matches no training view ({shown})")
    return names.index(name)


def _view_of_file(names: list[str], path: Path) -> str:
    """The training view a reference file colours: its stem (``r_013.png`` -> ``r_013``), or, where views are named
    with their folder because stems repeat (:func:`~arcsem.names.view_names`: ``train/r_0``), the file's last
    path components (``.../train/r_0.png``: a NeRF-synthetic folder's own colour image). The stem if none is a view."""
    from ..names import safe_name

    parts = path.with_suffix("").parts
    for k in range(1, len(parts) + 1):
        if safe_name(parts[-k:]) in names:
            return safe_name(parts[-k:])
    return path.stem


def _true_colour_view(train, item) -> bool:
    """Whether a list item of ``colorize.references`` names a training view with ground-truth colour (and is no file
    or folder): the reference is then that colour."""
    return train.colors is not None and str(item) in train.names and not Path(item).exists()


def load_references(scene, spec: str | list[str]) -> References:
    """References for ``scene`` from a preset name (``"five"`` ...) or a list of image files/folders.

    Args:
        scene: :class:`arcsem.scene.Scene`; its ``train`` split gives names and sizes.
        spec: a preset in ``scene.reference_sets`` (a bare word: ``one``, even where a folder ``one`` exists), a
            path (written with ``/`` or ``.``: ``./one``, ``refs/a.png``), or a list of paths (a folder means
            every image file in it) and of training views with ground-truth colour (``[train/r_0, train/r_50]``:
            that colour is the reference; a file or folder of the same name wins).
    """
    train = scene.train
    hw = (train.cameras.height, train.cameras.width)
    if isinstance(spec, str) and "/" not in spec and "." not in spec:  # a bare word names a preset, never a path
        if spec not in scene.reference_sets:
            path = f"; for the file or folder '{spec}' write ./{spec}" if Path(spec).exists() else ""
            if _true_colour_view(train, spec):
                path += f"; for view '{spec}''s true colour write [{spec}]"
            raise ConfigError(
                f"colorize.references: unknown preset '{spec}'; the dataset has: "
                f"{', '.join(scene.reference_sets) or 'none'}{path}"
            )
        names = list(scene.reference_sets[spec])
        images = []
        for n in names:
            if n not in scene.references:
                raise DataError(f"reference preset '{spec}': no colour image for view '{n}' in the scene")
            images.append(check_reference(n, scene.references[n], hw, f"'{n}' (preset {spec})"))
    else:
        names, images = [], []
        for item in [spec] if isinstance(spec, (str, Path)) else list(spec):
            if _true_colour_view(train, item):  # a view's own ground-truth colour (benchmarks; dataset.grey=true)
                names.append(str(item))
                images.append(check_reference(str(item), train.colors[train.names.index(str(item))], hw,
                                              f"view '{item}' (its true colour)"))
                continue
            for f in _expand_files([item]):
                name = _view_of_file(train.names, f)
                _view_index(train.names, name, f"'{f}'")
                images.append(check_reference(name, _read_image(f), hw, f"'{f}'"))
                names.append(name)
    if not names:
        raise ConfigError(f"references: '{spec}' gives no reference image")
    if len(set(names)) != len(names):
        raise DataError(f"references: view named twice in {names}")
    idx = torch.tensor([_view_index(train.names, n, f"'{n}'") for n in names], dtype=torch.long)
    return References(names=names, indices=idx, images=torch.stack(images))


def _expand_files(items: list) -> list[Path]:
    out: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            out += sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_EXTS)
        elif p.is_file():
            out.append(p)
        else:
            raise DataError(f"reference file '{p}' does not exist (nor is it a training view with ground-truth colour)")
    return out
