"""Novel-view paths along the training cameras' arcs, and writing image sequences as video.

:func:`arc_path` walks through the training cameras in dataset order (for the paper's data: the
horizontal arc, then the vertical arc): between consecutive cameras the orientation is
slerped (quaternions) and the position is slerped around the scene centre with a linearly
interpolated radius, so the path stays on the arc instead of cutting the chord. Intrinsics are
interpolated linearly; every frame has ``image_id = -1`` (the mean ACT).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .cameras import Cameras
from .rotations import quat_to_rotmat, rotmat_to_quat

__all__ = ["arc_path", "slerp", "write_video"]


def slerp(a: Tensor, b: Tensor, t: Tensor) -> Tensor:
    """Spherical interpolation of unit vectors ``a, b [N,D]`` at ``t [N]`` (lerp when nearly parallel)."""
    dot = (a * b).sum(-1, keepdim=True).clamp(-1.0, 1.0)
    theta = torch.acos(dot)
    t = t[:, None]
    small = theta.abs() < 1e-6
    sin = torch.sin(theta).clamp_min(1e-12)
    wa = torch.where(small, 1 - t, torch.sin((1 - t) * theta) / sin)
    wb = torch.where(small, t, torch.sin(t * theta) / sin)
    out = wa * a + wb * b
    return out / out.norm(dim=-1, keepdim=True)


def arc_path(cams: Cameras, frames: int, center: Tensor) -> Cameras:
    """``frames`` cameras along the training cameras ``cams`` (in order), around ``center [3]``."""
    n = len(cams)
    c2w = cams.cam_to_world.double()
    if n == 1:
        return replace(cams[[0] * frames], image_ids=torch.full((frames,), -1, dtype=torch.long))
    t = torch.linspace(0, n - 1, frames, dtype=torch.float64)
    i = t.floor().long().clamp(max=n - 2)
    a = t - i
    q = rotmat_to_quat(c2w[:, :3, :3])
    q0, q1 = q[i], q[i + 1]
    q1 = torch.where((q0 * q1).sum(-1, keepdim=True) < 0, -q1, q1)  # shortest way round
    R = quat_to_rotmat(slerp(q0, q1, a))
    off = c2w[:, :3, 3] - center.double()
    r = off.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    d = slerp(off[i] / r[i], off[i + 1] / r[i + 1], a)
    pos = center.double() + d * ((1 - a[:, None]) * r[i] + a[:, None] * r[i + 1])
    new = torch.eye(4, dtype=torch.float64).repeat(frames, 1, 1)
    new[:, :3, :3], new[:, :3, 3] = R, pos
    K = (1 - a[:, None, None]) * cams.K.double()[i] + a[:, None, None] * cams.K.double()[i + 1]
    dtype = cams.world_to_cam.dtype
    return replace(cams, world_to_cam=torch.linalg.inv(new).to(dtype), K=K.to(dtype),
                   image_ids=torch.full((frames,), -1, dtype=torch.long))


def write_video(path: str | Path, frames: list[np.ndarray], fps: int = 20) -> Path:
    """Write ``uint8 [H,W,3]`` frames as MP4 (imageio-ffmpeg, H.264, yuv420p); falls back to GIF. Returns the path."""
    import imageio.v2 as imageio

    path = Path(path)
    h, w = frames[0].shape[:2]
    even = [np.pad(f, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge") for f in frames]  # yuv420p needs even sizes
    try:
        imageio.mimwrite(path.with_suffix(".mp4"), even, fps=fps, codec="libx264", quality=8, macro_block_size=1,
                         pixelformat="yuv420p")  # what browsers play
        return path.with_suffix(".mp4")
    except Exception:  # noqa: BLE001  (no ffmpeg binary / codec: a GIF always works)
        path.with_suffix(".mp4").unlink(missing_ok=True)
        imageio.mimwrite(path.with_suffix(".gif"), frames, duration=1000 / fps, loop=0)
        return path.with_suffix(".gif")
