"""One camera batch type for pinhole and orthographic cameras (OpenCV axes).

Conventions, used by every backbone, reader and the pseudo-colour code:

* camera axes: x right, y down, z forward (OpenCV / COLMAP);
* ``world_to_cam`` ``[C, 4, 4]`` maps world points to camera coordinates;
* ``K`` ``[C, 3, 3]``: ``fx, fy`` in pixels (pinhole: per unit of ``x/z``; orthographic: per world
  unit), ``cx, cy`` the principal point in pixels;
* pixel ``(i, j)`` (column, row) has its centre at ``(i + 0.5, j + 0.5)`` (COLMAP / NeRF);
* depth is the camera-space ``z`` (not the distance along the ray); ray directions returned by
  :meth:`Cameras.rays` have unit ``z`` in camera space, so ``origin + depth * direction`` is the
  point at that depth for both models.

Orthographic projection: ``u = fx * x + cx``, ``v = fy * y + cy``; rays start on the camera plane
``z = 0`` and all point along the camera's forward axis.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import torch
from torch import Tensor

__all__ = ["CameraModel", "Cameras", "look_at", "opengl_to_opencv"]

CameraModel = Literal["pinhole", "orthographic"]
MODELS = ("pinhole", "orthographic")


@dataclass
class Cameras:
    """A batch of ``C`` cameras sharing one model and one image size.

    Attributes:
        world_to_cam: ``[C, 4, 4]`` world -> camera (OpenCV axes).
        K: ``[C, 3, 3]`` intrinsics.
        width, height: image size in pixels.
        model: ``"pinhole"`` or ``"orthographic"``.
        image_ids: ``[C]`` long, index of the training image (selects its ACT); ``-1`` for novel views.
    """

    world_to_cam: Tensor
    K: Tensor
    width: int
    height: int
    model: CameraModel = "pinhole"
    image_ids: Tensor | None = None

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown camera model '{self.model}'; expected one of {MODELS}")
        if self.world_to_cam.ndim == 2:
            self.world_to_cam = self.world_to_cam[None]
        if self.K.ndim == 2:
            self.K = self.K[None]
        C = self.world_to_cam.shape[0]
        if self.world_to_cam.shape != (C, 4, 4) or self.K.shape != (C, 3, 3):
            raise ValueError(f"cameras: world_to_cam {tuple(self.world_to_cam.shape)} / K {tuple(self.K.shape)}")
        if self.image_ids is None:
            self.image_ids = torch.full((C,), -1, dtype=torch.long, device=self.world_to_cam.device)

    # ---------------------------------------------------------------- batch plumbing
    def __len__(self) -> int:
        return self.world_to_cam.shape[0]

    def __getitem__(self, idx) -> Cameras:
        if isinstance(idx, int):
            idx = slice(idx, idx + 1) if idx >= 0 else slice(idx, (idx + 1) or None)
        out = replace(self, world_to_cam=self.world_to_cam[idx], K=self.K[idx], image_ids=self.image_ids[idx])
        stamp = self._stamp()
        if stamp is not None:  # a training batch: its derived values are slices of this batch's (:meth:`derived`)
            out.__dict__["_parent"] = (self, stamp, idx)
        return out

    def to(self, device=None, dtype=None) -> Cameras:
        out = replace(
            self,
            world_to_cam=self.world_to_cam.to(device=device, dtype=dtype),
            K=self.K.to(device=device, dtype=dtype),
            image_ids=self.image_ids.to(device=device),
        )
        if out.world_to_cam is self.world_to_cam and out.K is self.K:  # nothing moved: the derived values hold
            for k in ("_derived", "_parent"):
                if k in self.__dict__:
                    out.__dict__[k] = self.__dict__[k]
        return out

    # ---------------------------------------------------------------- values derived from poses and intrinsics
    def _stamp(self) -> tuple | None:
        """What derived values depend on: the pose and intrinsics tensors and their in-place versions (None: they
        need gradients, so nothing is kept: a graph would outlive its step)."""
        w, K = self.world_to_cam, self.K
        if w.requires_grad or K.requires_grad:
            return None
        return (w, w._version, K, K._version)

    def _derived_now(self) -> dict:
        """What is kept and still holds (``{}``: nothing)."""
        kept = self.__dict__.get("_derived")
        if kept is None or not _same(kept[0], self._stamp()):
            return {}
        return kept[1]

    def derived(self, key, make):
        """``make(self)``: a tensor (or tuple of tensors) with a leading camera axis that depends only on the poses
        and intrinsics, kept on this batch under ``key`` while they stay the same tensors, unchanged in place and not
        differentiable. A batch indexed from this one (``cams[idx]``, a training step's) takes the slice of this
        batch's value, made once for the whole batch. A training step asks for the centres, the projection matrices
        and the like several times, each tens of operators a GPU's host would issue (benchmarks/gpu/op_count.py)."""
        values = self._derived_now()
        if key in values:
            return values[key]
        stamp, parent = self._stamp(), self.__dict__.get("_parent")
        if stamp is not None and parent is not None and _same(parent[1], parent[0]._stamp()):
            value = _slice(parent[0].derived(key, make), parent[2])
        else:
            value = make(self)
        if stamp is not None:
            self.__dict__["_derived"] = (stamp, {**values, key: value})
        return value

    @staticmethod
    def cat(batches: list[Cameras]) -> Cameras:
        first = batches[0]
        for b in batches[1:]:
            if (b.width, b.height, b.model) != (first.width, first.height, first.model):
                raise ValueError("Cameras.cat: batches differ in size or model")
        return replace(
            first,
            world_to_cam=torch.cat([b.world_to_cam for b in batches]),
            K=torch.cat([b.K for b in batches]),
            image_ids=torch.cat([b.image_ids for b in batches]),
        )

    @property
    def device(self) -> torch.device:
        return self.world_to_cam.device

    @property
    def is_ortho(self) -> bool:
        return self.model == "orthographic"

    @property
    def cam_to_world(self) -> Tensor:
        """``[C, 4, 4]`` camera -> world."""
        return torch.linalg.inv(self.world_to_cam)

    @property
    def centers(self) -> Tensor:
        """``[C, 3]`` camera centres (for orthographic cameras: the origin of the camera plane).

        Kept (:meth:`derived`): a render asks for them several times (SH view directions, projection, normals,
        densification), each ten operators."""
        return self.derived("centers", _centers)

    @property
    def forward(self) -> Tensor:
        """``[C, 3]`` unit viewing direction (camera +z) in world coordinates."""
        return self.world_to_cam[:, 2, :3]

    def scaled(self, factor: float) -> Cameras:
        """Cameras for images resized by ``factor`` (0.5 = half size); pixel centres stay consistent."""
        K = self.K.clone()
        K[:, :2, :] *= factor
        w, h = round(self.width * factor), round(self.height * factor)
        return replace(self, K=K, width=w, height=h)

    # ---------------------------------------------------------------- geometry
    def pixel_grid(self, dtype=torch.float32) -> Tensor:
        """``[H, W, 2]`` pixel centres ``(x, y)``."""
        ys, xs = torch.meshgrid(
            torch.arange(self.height, device=self.device, dtype=dtype) + 0.5,
            torch.arange(self.width, device=self.device, dtype=dtype) + 0.5,
            indexing="ij",
        )
        return torch.stack([xs, ys], -1)

    def to_camera(self, points: Tensor) -> Tensor:
        """World points ``[C, N, 3]`` (or ``[N, 3]``, broadcast) -> camera coordinates ``[C, N, 3]``."""
        if points.ndim == 2:
            points = points[None].expand(len(self), -1, -1)
        R, t = self.world_to_cam[:, :3, :3], self.world_to_cam[:, :3, 3]
        # in place on the product (autograd allows it: the product's backward does not read its output); for millions
        # of points (mesh fusion) one pass and one allocation less
        return (points @ R.transpose(1, 2)).add_(t[:, None, :])

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """World points ``[C, N, 3]`` or ``[N, 3]`` -> pixels ``[C, N, 2]`` and depth ``[C, N]``."""
        pc = self.to_camera(points)
        z = pc[..., 2]
        xy = pc[..., :2] if self.is_ortho else pc[..., :2] / z[..., None]
        f = torch.stack([self.K[:, 0, 0], self.K[:, 1, 1]], -1)[:, None, :]
        c = self.K[:, :2, 2][:, None, :]
        skew = self.K[:, 0, 1][:, None]
        uv = xy * f + c
        uv[..., 0] += skew * xy[..., 1]  # u = fx x + cx + s y, in place on a fresh tensor (the same sums)
        return uv, z

    def pixels_to_camera(self, uv: Tensor, depth: Tensor) -> Tensor:
        """Pixels ``[C, N, 2]`` with depth ``[C, N]`` -> camera-space points ``[C, N, 3]``."""
        fx, fy = self.K[:, 0, 0][:, None], self.K[:, 1, 1][:, None]
        cx, cy, s = self.K[:, 0, 2][:, None], self.K[:, 1, 2][:, None], self.K[:, 0, 1][:, None]
        y = (uv[..., 1] - cy) / fy
        x = (uv[..., 0] - cx - s * y) / fx
        if not self.is_ortho:
            x, y = x * depth, y * depth
        return torch.stack([x, y, depth], -1)

    def unproject_points(self, uv: Tensor, depth: Tensor) -> Tensor:
        """Pixels ``[C, N, 2]`` with depth ``[C, N]`` -> world points ``[C, N, 3]``."""
        pc = self.pixels_to_camera(uv, depth)
        c2w = self.cam_to_world
        return pc @ c2w[:, :3, :3].transpose(1, 2) + c2w[:, None, :3, 3]

    def unproject(self, depth: Tensor) -> Tensor:
        """Depth maps ``[C, H, W]`` (or ``[C, H, W, 1]``) -> world points ``[C, H, W, 3]``."""
        if depth.ndim == 4:
            depth = depth[..., 0]
        C, H, W = depth.shape
        uv = self.pixel_grid(depth.dtype).reshape(1, H * W, 2).expand(C, -1, -1)
        return self.unproject_points(uv, depth.reshape(C, H * W)).reshape(C, H, W, 3)

    def rays(self, uv: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Ray origins and directions in world space.

        Args:
            uv: ``[C, N, 2]`` pixel coordinates; default: every pixel centre.
        Returns:
            origins, directions: ``[C, N, 3]`` (or ``[C, H, W, 3]`` for the full grid). Directions have
            unit camera-space ``z``: ``origin + depth * direction`` is the point at z-depth ``depth``.
        """
        full = uv is None
        if full:
            uv = self.pixel_grid(self.K.dtype).reshape(1, -1, 2).expand(len(self), -1, -1)
        zeros, ones = torch.zeros_like(uv[..., 0]), torch.ones_like(uv[..., 0])
        c2w = self.cam_to_world
        R, t = c2w[:, :3, :3], c2w[:, :3, 3]
        if self.is_ortho:
            o_cam = self.pixels_to_camera(uv, zeros)
            d_cam = torch.stack([zeros, zeros, ones], -1)
        else:
            o_cam = torch.zeros(*uv.shape[:-1], 3, dtype=uv.dtype, device=uv.device)
            d_cam = self.pixels_to_camera(uv, ones)
        origins = o_cam @ R.transpose(1, 2) + t[:, None, :]
        dirs = d_cam @ R.transpose(1, 2)
        if full:
            shape = (len(self), self.height, self.width, 3)
            origins, dirs = origins.reshape(shape), dirs.reshape(shape)
        return origins, dirs


def opengl_to_opencv(c2w: Tensor) -> Tensor:
    """Camera-to-world ``[..., 4, 4]`` in OpenGL axes (x right, y up, z back) -> OpenCV axes."""
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=c2w.dtype, device=c2w.device))
    return c2w @ flip


def _centers(cams: Cameras) -> Tensor:
    R, t = cams.world_to_cam[:, :3, :3], cams.world_to_cam[:, :3, 3]
    return -(R.transpose(1, 2) @ t[..., None])[..., 0]


def _same(a: tuple | None, b: tuple | None) -> bool:
    """Whether two :meth:`Cameras._stamp` name the same tensors at the same versions."""
    return a is not None and b is not None and all((x is y) if i % 2 == 0 else x == y for i, (x, y) in enumerate(zip(a, b)))


def _slice(value, idx):
    return tuple(v[idx] for v in value) if isinstance(value, tuple) else value[idx]


def look_at(eye: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """World -> camera ``[C, 4, 4]`` (OpenCV axes) for cameras at ``eye [C,3]`` looking at ``target [C,3]``.

    ``up [3]`` or ``[C, 3]`` is the world direction that appears upwards in the image (camera -y).
    """
    eye, target = torch.as_tensor(eye), torch.as_tensor(target, dtype=eye.dtype)
    up = torch.as_tensor(up, dtype=eye.dtype).expand_as(eye)
    z = torch.nn.functional.normalize(target - eye, dim=-1)
    x = torch.nn.functional.normalize(torch.cross(z, up, dim=-1), dim=-1)
    y = torch.cross(z, x, dim=-1)
    R = torch.stack([x, y, z], -2)  # rows: camera axes in world coordinates
    w2c = torch.eye(4, dtype=eye.dtype).repeat(eye.shape[0], 1, 1)
    w2c[:, :3, :3] = R
    w2c[:, :3, 3] = -(R @ eye[..., None])[..., 0]
    return w2c
