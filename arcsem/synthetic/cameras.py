"""Camera arcs of the synthetic scene, like the paper's acquisition.

World axes: ``z`` up (the grain's polar axis). A camera at azimuth ``az`` and elevation ``el``
(degrees) sits in direction ``(sin az cos el, -cos az cos el, sin el)`` from the origin and looks
at it, image-up towards ``+z``: ``az = el = 0`` is the frontal view (camera on ``-y``), ``az > 0``
moves it to the right, ``el = 90`` would be straight above.

* horizontal arc: ``n_horizontal`` views, azimuth ``-60 .. +60`` at elevation ``10`` (left to right);
* vertical arc: ``n_vertical`` views at azimuth ``0``, elevation ``0 .. 85`` (front to top);
* test views: half-way between consecutive training views, every ``test_every``-th gap of each arc.

Near-orthographic pinhole: the focal length is the paper's (50,000 px at 3072 px width, scaled
with the width) and the distance is chosen so that the grain spans ``fill`` (90%) of the image
height (about 60% of the width at 3:2; a top view of the round grain must fit the height).
The orthographic variant has the same pixel footprint at the origin (``fl_x`` = pixels per unit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..cameras import Cameras, look_at

__all__ = ["PAPER_FOCAL", "PAPER_WIDTH", "ViewSpec", "arc_cameras", "arc_views", "view_direction"]

PAPER_FOCAL = 50_000.0   # px, the paper's calibrated focal length ...
PAPER_WIDTH = 3072       # ... at this image width
H_AZIMUTH = (-60.0, 60.0)
H_ELEVATION = 10.0
V_ELEVATION = (0.0, 85.0)


@dataclass(frozen=True)
class ViewSpec:
    """One view: ``name``, ``split`` ("train"|"test"), ``arc`` ("h"|"v"), angles in degrees."""

    name: str
    split: str
    arc: str
    azimuth: float
    elevation: float


def _lerp(a: float, b: float, x: float) -> float:
    return a + (b - a) * x


def arc_views(n_horizontal: int = 20, n_vertical: int = 12, test_every: int = 4) -> list[ViewSpec]:
    """Training views of both arcs followed by the test views (names ``h_00``, ``v_00``, ``test_h_01``...).

    ``test_h_k`` lies half-way between ``h_k`` and ``h_{k+1}``; gaps ``1, 1 + test_every, ...`` get one.
    """
    views = []
    nh, nv = max(n_horizontal - 1, 1), max(n_vertical - 1, 1)
    for i in range(n_horizontal):
        views.append(ViewSpec(f"h_{i:02d}", "train", "h", _lerp(*H_AZIMUTH, i / nh), H_ELEVATION))
    for i in range(n_vertical):
        views.append(ViewSpec(f"v_{i:02d}", "train", "v", 0.0, _lerp(*V_ELEVATION, i / nv)))
    for i in range(1, n_horizontal - 1, test_every):
        views.append(ViewSpec(f"test_h_{i:02d}", "test", "h", _lerp(*H_AZIMUTH, (i + 0.5) / nh), H_ELEVATION))
    for i in range(1, n_vertical - 1, test_every):
        views.append(ViewSpec(f"test_v_{i:02d}", "test", "v", 0.0, _lerp(*V_ELEVATION, (i + 0.5) / nv)))
    return views


def view_direction(azimuth: float, elevation: float) -> torch.Tensor:
    """``[3]`` float64 unit vector from the origin towards a camera at these angles (degrees)."""
    az, el = math.radians(azimuth), math.radians(elevation)
    return torch.tensor([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)],
                        dtype=torch.float64)


def arc_cameras(
    views: list[ViewSpec], width: int, height: int, camera: str = "pinhole", extent: float = 2.5,
    fill: float = 0.9,
) -> tuple[Cameras, float]:
    """float64 ``Cameras`` for ``views`` and the camera distance.

    ``extent``: world width of the grain (spines included) that should span ``fill`` of the image
    height (the smaller side at 3:2, so that the top view is not cropped; 60% of the width at 3:2).
    """
    if camera not in ("pinhole", "orthographic"):
        raise ValueError(f"camera must be 'pinhole' or 'orthographic', got '{camera}'")
    focal = PAPER_FOCAL * width / PAPER_WIDTH
    px_per_unit = fill * min(width, height) / extent
    distance = focal / px_per_unit
    f = focal if camera == "pinhole" else px_per_unit
    dirs = torch.stack([view_direction(v.azimuth, v.elevation) for v in views])
    eye = dirs * distance
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)
    cams = Cameras(w2c, K.expand(len(views), 3, 3).clone(), width, height, camera)
    return cams, distance
