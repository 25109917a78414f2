"""The one scene type every dataset reader returns and every stage consumes.

Images are float32 in ``[0, 1]`` with three channels (grey images are three equal channels).
Optional per-view ground truth (``depths``, ``normals``, ``colors``) exists for synthetic scenes;
real data leaves it ``None``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from .cameras import Cameras

__all__ = ["Scene", "Split", "scene_fingerprint"]


@dataclass
class Split:
    """The views of one split (train or test). ``N`` views of ``H x W`` pixels.

    Attributes:
        names: ``N`` view names (file stem of the image, e.g. ``"r_013"``), unique.
        cameras: ``N`` cameras; ``image_ids`` = training index for train views, -1 for test views.
        images: ``[N, H, W, 3]`` float32 in [0, 1], the observed (grey) images.
        masks: ``[N, H, W]`` bool specimen masks, or None.
        depths: ``[N, H, W]`` ground-truth z-depth (0 = background), or None.
        normals: ``[N, H, W, 3]`` ground-truth world normals, or None.
        colors: ``[N, H, W, 3]`` ground-truth colour images, or None.
        clean: ``[N, H, W, 3]`` noise-free grey images (synthetic ground truth), or None.
        files: ``N`` image paths the views were read from (for messages and output names).
    """

    names: list[str]
    cameras: Cameras
    images: Tensor
    masks: Tensor | None = None
    depths: Tensor | None = None
    normals: Tensor | None = None
    colors: Tensor | None = None
    clean: Tensor | None = None
    files: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no view named '{name}'; views: {', '.join(self.names)}") from None

    def subset(self, idx: list[int] | Tensor) -> Split:
        """The views ``idx`` (cameras keep their ``image_ids``)."""
        idx = torch.as_tensor(idx, dtype=torch.long)
        pick = lambda t: None if t is None else t[idx]
        return replace(
            self,
            names=[self.names[i] for i in idx.tolist()],
            cameras=self.cameras[idx],
            images=self.images[idx],
            masks=pick(self.masks),
            depths=pick(self.depths),
            normals=pick(self.normals),
            colors=pick(self.colors),
            clean=pick(self.clean),
            files=[self.files[i] for i in idx.tolist()] if self.files else [],
        )


@dataclass
class Scene:
    """A dataset: train and test views, optional colour references, point cloud and bounds.

    Attributes:
        root: folder the scene was read from.
        train, test: the splits (``test`` may hold zero views).
        bounds: ``[2, 3]`` axis-aligned box (min, max) that contains the specimen.
        points: ``[P, 3]`` initial point cloud, or None. ``point_colors``: ``[P, 3]`` in [0, 1], or None.
        references: artist colour images by training-view name, ``{name: [H, W, 3]}``.
        reference_sets: named presets -> list of training-view names (``five``, ``four``, ...).
        specimen_size: the specimen's diameter in world units when the dataset states it (transforms
            key ``specimen_size``; the synthetic grain's ``grain_size``), else None: see :attr:`scale`.
        micrometres_per_unit: the physical length of one world unit when the dataset gives its images'
            pixel size (transforms key ``pixel_size_um``), else None (lengths stay in scene units).
        extent: scene extent used by Gaussian learning rates (see :attr:`extent`).
        bounds_source: where ``bounds`` come from: ``"given"`` (the dataset's ``aabb``, or whoever built
            the scene), ``"points"`` (percentiles of the point cloud) or ``"cameras"`` (the frusta).
        warnings: what the reader noticed and decided (an alpha channel ignored, colour views), one line each.
        content_bounds: ``[2, 3]`` box of everything the views show (substrate and debris too) where the dataset
            gives it (transforms key ``content_aabb``, written by ``arcsem-calibrate``), else None. The Plenoxels
            grid spans it; ``bounds`` stays the specimen's, the length scale of the Gaussians.
        intensity: the intensity ranges the image files were read over, one entry per distinct range
            (``{"levels": "0..65535 (16-bit samples)", "views": 32, "first": path}``); empty for generated scenes.
    """

    root: str
    train: Split
    test: Split
    bounds: Tensor
    points: Tensor | None = None
    point_colors: Tensor | None = None
    references: dict[str, Tensor] = field(default_factory=dict)
    reference_sets: dict[str, list[str]] = field(default_factory=dict)
    specimen_size: float | None = None
    micrometres_per_unit: float | None = None
    bounds_source: str = "given"
    warnings: list[str] = field(default_factory=list)
    intensity: list[dict] = field(default_factory=list)
    content_bounds: Tensor | None = None

    @property
    def extent(self) -> float:
        """Length scale of the Gaussian learning rates and densification thresholds.

        3DGS uses 1.1 x the radius of the camera centres, the right scale when the cameras surround
        the scene at a few object sizes. SEM cameras sit far away (pinhole at ~30 grain sizes) or
        anywhere (orthographic), so the scale is capped by 1.1 x the bounding-box diagonal: otherwise
        the position lr and the clone/split threshold (``percent_dense x extent``) would be tens of
        times the specimen's scale.
        """
        box = float(1.1 * (self.bounds[1] - self.bounds[0]).norm())
        if self.train.cameras.is_ortho:
            return box
        centers = self.train.cameras.centers
        return min(box, float(1.1 * (centers - centers.mean(0)).norm(dim=-1).max()))

    @property
    def size(self) -> float:
        """Diameter of the bounding box (a length scale for tolerances)."""
        return float((self.bounds[1] - self.bounds[0]).norm())

    @property
    def scale(self) -> tuple[float, str]:
        """The length that relative depth errors are quoted in, and its name: the specimen's
        diameter where the dataset states it, else the bounding-box diagonal."""
        if self.specimen_size:
            return float(self.specimen_size), "specimen diameter"
        return self.size, "bounding-box diagonal"


def scene_fingerprint(scene: Scene) -> dict:
    """What identifies a dataset whatever its folder and resolution: a hash of the view names (in order),
    the camera model and the poses (to 1e-4), plus the view counts for messages. A stage-1 model records
    it; stage 2 refuses a model trained on another dataset."""
    import hashlib

    h = hashlib.sha256()
    for split in (scene.train, scene.test):
        h.update(("|".join(split.names) + f"#{split.cameras.model}#").encode())
        if len(split):
            pose = split.cameras.world_to_cam[:, :3, :4].double()
            h.update(torch.round(pose * 1e4).to(torch.int64).numpy().tobytes())
    return {"hash": h.hexdigest()[:16], "train_views": len(scene.train), "test_views": len(scene.test)}
