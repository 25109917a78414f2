"""Cameras on an orbit around the specimen, for videos, mesh fusion and the viewer.

The orbit's frame is derived from the training cameras, so it works for any dataset:

* ``up``: the direction most orthogonal to the training cameras' image-right axes (cameras without
  roll keep their x axis horizontal, so for SEM arcs, and the built-in scene whose world ``z`` is up,
  this is the stage's vertical), signed like their mean image-up (camera ``-y``); when all right
  axes are parallel (a single vertical arc), the mean image-up made orthogonal to them;
* ``centre``: the centre of the scene bounds;
* azimuth ``0``: the mean viewing direction of the training cameras, projected on the plane
  orthogonal to ``up`` (the orbit starts in front of the specimen, as the operator saw it);
  elevation ``0`` is in that plane, ``+90`` looks straight down along ``-up``;
* pinhole cameras sit at the training cameras' mean distance from the centre; orthographic cameras
  sit outside the bounds (their image does not depend on the distance).

Intrinsics are the first training camera's, scaled to the requested width, with the principal
point at the image centre (the specimen is in the middle of every frame).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .cameras import Cameras, look_at
from .errors import ConfigError

__all__ = ["OrbitConfig", "OrbitFrame", "camera_angles", "orbit_cameras", "orbit_frame", "orbit_on_frame",
           "view_cameras"]


@dataclass
class OrbitConfig:
    """An orbit: ``frames`` views from ``azimuth[0]`` to ``azimuth[1]`` (degrees) at ``elevation``."""

    frames: int = 200  # 10 s at 20 fps
    azimuth: tuple[float, float] = (0.0, 360.0)  # start, end (degrees); 0 = in front of the specimen
    elevation: float = 20.0  # degrees above the orbit plane
    width: int | None = None  # None: the training width
    height: int | None = None  # None: keep the training aspect ratio
    camera: str | None = None  # pinhole | orthographic; None: the training cameras' model
    zoom: float = 1.0  # > 1 magnifies

    def validate(self) -> OrbitConfig:
        if int(self.frames) < 1:
            raise ConfigError(f"orbit frames must be >= 1, got {self.frames}")
        if len(tuple(self.azimuth)) != 2:
            raise ConfigError(f"orbit azimuth must be [start, end] in degrees, got {self.azimuth}")
        if not -90.0 <= float(self.elevation) <= 90.0:
            raise ConfigError(f"orbit elevation must be in [-90, 90] degrees, got {self.elevation}")
        for key in ("width", "height"):
            v = getattr(self, key)
            if v is not None and int(v) < 8:
                raise ConfigError(f"orbit {key} must be >= 8 pixels, got {v}")
        if self.camera not in (None, "pinhole", "orthographic"):
            raise ConfigError(f"orbit camera must be pinhole or orthographic, got '{self.camera}'")
        if not float(self.zoom) > 0:
            raise ConfigError(f"orbit zoom must be > 0, got {self.zoom}")
        return self


@dataclass
class OrbitFrame:
    """The orbit's frame: ``centre [3]``, unit ``up [3]``, unit ``front [3]`` (azimuth 0, from the
    centre towards the cameras), ``radius`` (pinhole camera distance) and ``size`` (bounds diagonal)."""

    centre: Tensor
    up: Tensor
    front: Tensor
    radius: float
    size: float


def _up(right: Tensor, mean_up: Tensor) -> Tensor:
    """Unit vector most orthogonal to the rows of ``right [C, 3]``, on the side of ``mean_up [3]``."""
    evals, evecs = torch.linalg.eigh(right.T @ right)
    up = evecs[:, 0]
    if evals[1] < 1e-6 * evals[2]:  # every right axis parallel: any vector orthogonal to them fits
        r = right[0] / right[0].norm()
        up = mean_up - (mean_up @ r) * r
    up = up / up.norm().clamp_min(1e-12)
    return -up if float(up @ mean_up) < 0 else up


def orbit_frame(train: Cameras, bounds: Tensor) -> OrbitFrame:
    """The orbit frame of training cameras ``train`` around the box ``bounds [2, 3]``."""
    c2w = train.cam_to_world.double()
    centre = bounds.double().mean(0)
    up = _up(c2w[:, :3, 0], -c2w[:, :3, 1].mean(0))
    front = -c2w[:, :3, 2].mean(0)  # from the specimen towards the cameras
    front = front - (front @ up) * up
    if front.norm() < 1e-6:  # all cameras look along `up`: any horizontal direction
        front = torch.linalg.svd(up[None])[2][-1]
    front = front / front.norm()
    size = float((bounds[1] - bounds[0]).double().norm())
    dist = (train.centers.double() - centre).norm(dim=-1).mean()
    radius = float(dist) if not train.is_ortho else 2.0 * size
    return OrbitFrame(centre, up, front, radius, size)


def camera_angles(cams: Cameras, frame: OrbitFrame) -> tuple[Tensor, Tensor]:
    """Azimuth and elevation ``[C]`` (degrees) of cameras on the orbit ``frame`` (their viewing
    direction, reversed: where they look from)."""
    d = -cams.forward.double()
    side = torch.linalg.cross(frame.up, frame.front)
    el = torch.rad2deg(torch.asin((d @ frame.up).clamp(-1, 1)))
    az = torch.rad2deg(torch.atan2(d @ side, d @ frame.front))
    return az, el


def view_cameras(frame: OrbitFrame, azimuth: Tensor, elevation: Tensor, template: Cameras,
                 width: int, height: int, model: str, zoom: float = 1.0, radius: float | None = None) -> Cameras:
    """Cameras at ``azimuth, elevation [F]`` (degrees) on ``frame``, looking at its centre.

    ``template``: a training camera whose focal length (scaled to ``width``) the new cameras take;
    an orthographic camera built from a pinhole template keeps the pixel footprint at the centre.
    """
    az, el = torch.deg2rad(azimuth.double()), torch.deg2rad(elevation.double())
    side = torch.linalg.cross(frame.up, frame.front)
    dirs = (torch.cos(el)[:, None] * (torch.cos(az)[:, None] * frame.front + torch.sin(az)[:, None] * side)
            + torch.sin(el)[:, None] * frame.up)
    r = frame.radius if radius is None else radius
    eye = frame.centre + r * dirs
    up = frame.up.expand_as(eye).clone()
    straight = (dirs @ frame.up).abs() > 1 - 1e-9  # looking along `up`: roll the image-up to `front`
    up[straight] = -frame.front
    w2c = look_at(eye, frame.centre.expand_as(eye), up)
    scale = width / template.width
    f = float(template.K[0, 0, 0]) * scale * zoom
    if model != template.model:
        t_dist = float((template.centers[0].double() - frame.centre).norm())
        f = f / t_dist if model == "orthographic" else f * frame.radius  # px per unit <-> px per x/z
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)
    return Cameras(w2c, K.expand(len(eye), 3, 3).clone(), width, height, model)


def orbit_cameras(train: Cameras, bounds: Tensor, cfg: OrbitConfig | None = None) -> Cameras:
    """``cfg.frames`` float32 cameras on the orbit (``image_ids = -1``: the mean ACT)."""
    cfg = (cfg or OrbitConfig()).validate()
    frame = orbit_frame(train, bounds)
    return orbit_on_frame(frame, train, cfg)


def orbit_on_frame(frame: OrbitFrame, train: Cameras, cfg: OrbitConfig) -> Cameras:
    """:func:`orbit_cameras` on a given frame."""
    cfg = cfg.validate()
    n = int(cfg.frames)
    a0, a1 = (float(a) for a in cfg.azimuth)
    closed = math.isclose(abs(a1 - a0) % 360.0, 0.0) and a1 != a0
    az = torch.linspace(a0, a1, n + 1 if closed else n, dtype=torch.float64)[:n]  # a full turn: no repeat
    el = torch.full_like(az, float(cfg.elevation))
    width = int(cfg.width or train.width)
    height = int(cfg.height or round(train.height * width / train.width))
    model = cfg.camera or train.model
    return view_cameras(frame, az, el, train[0], width, height, model, float(cfg.zoom)).to(dtype=torch.float32)
