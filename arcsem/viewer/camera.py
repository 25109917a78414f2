"""The browser's camera as arcsem :class:`~arcsem.cameras.Cameras`, and where to draw training cameras.

viser reports the camera as a camera-to-world rotation (quaternion ``wxyz``) and position in
OpenCV axes (x right, y down, z forward; the convention arcsem uses), a vertical field of view and
the point it orbits (``look_at``). A pinhole camera takes the field of view as it is; an
orthographic one shows, at the orbit point, the same extent the pinhole view shows there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..cameras import Cameras

__all__ = ["ViewState", "frustum_poses", "rotmat_to_wxyz", "state_cameras", "wxyz_to_rotmat"]


@dataclass(frozen=True)
class ViewState:
    """A snapshot of the browser camera: ``wxyz [4]``, ``position [3]``, ``look_at [3]``, vertical
    ``fov`` (radians) and ``aspect`` (width / height)."""

    wxyz: tuple[float, ...]
    position: tuple[float, ...]
    look_at: tuple[float, ...]
    fov: float
    aspect: float


def wxyz_to_rotmat(q) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` -> rotation matrix ``[3, 3]``."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrix ``[3, 3]`` -> unit quaternion ``(w, x, y, z)`` with ``w >= 0``."""
    from ..rotations import rotmat_to_quat

    return rotmat_to_quat(torch.as_tensor(R, dtype=torch.float64)[None])[0].numpy()


def state_cameras(s: ViewState, height: int, model: str = "pinhole") -> Cameras:
    """One float32 camera of ``height`` pixels (width from the aspect) for the view ``s``."""
    height = max(int(height), 8)
    width = max(round(height * s.aspect), 8)
    c2w = np.eye(4)
    c2w[:3, :3] = wxyz_to_rotmat(s.wxyz)
    c2w[:3, 3] = s.position
    w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float64)
    f = height / (2.0 * math.tan(s.fov / 2.0))  # pinhole: pixels per unit of x/z
    if model == "orthographic":
        dist = max(float(np.linalg.norm(np.subtract(s.look_at, s.position))), 1e-9)
        f = f / dist  # pixels per world unit at the orbit point
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)
    return Cameras(w2c, K, width, height, model).to(dtype=torch.float32)


def frustum_poses(cams: Cameras, centre: np.ndarray, size: float, far: float = 3.0) -> list[tuple]:
    """``[(wxyz, position, fov, aspect)]`` of training cameras to draw; a camera farther than ``far``
    x ``size`` from ``centre`` (SEM cameras sit at tens of specimen sizes) is drawn at that distance on
    its true line of sight, so frusta and specimen fit one view."""
    c2w = cams.cam_to_world.double().numpy()
    out = []
    for i in range(len(cams)):
        pos = c2w[i, :3, 3]
        off = pos - centre
        dist = float(np.linalg.norm(off))
        if dist > far * size:
            pos = centre + off / dist * far * size
        fy = float(cams.K[i, 1, 1])
        fov = 2 * math.atan(cams.height / (2 * fy)) if not cams.is_ortho else 2 * math.atan(
            cams.height / (2 * fy) / max(far * size, 1e-9))
        out.append((rotmat_to_wxyz(c2w[i, :3, :3]), pos, fov, cams.width / cams.height))
    return out
