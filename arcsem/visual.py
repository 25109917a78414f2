"""What a person looks at: a model's colour, depth and normal layers as images, and a colour bar.

One implementation shared by the videos (``stage=render``), the viewer (``arcsem-view``), the
evaluation renders and the report:

* :func:`render_layers` renders cameras and returns the layers: ``rgb``, the surface ``depth``
  (``median_depth`` where the backbone provides it, else the expected depth), ``valid`` (alpha >=
  ``alpha_min``) and world ``normal`` (the backbone's where it provides them, else from the depth
  map by :func:`depth_normals`);
* :func:`depth_rgb` colours depth with OpenCV's *turbo* map over a fixed range (near = red, far =
  blue), pixels outside ``valid`` in a flat background colour;
* :func:`normal_rgb` shows camera-space normals (``(n_x, -n_y, -n_z)`` mapped to RGB: a surface
  facing the camera is blue);
* :func:`depth_display` shows a depth map and its ground truth alike (the same pixels, one range of
  :data:`DEPTH_SPAN` x the specimen's size below the nearest ground-truth point);
* :func:`colour_bar` draws a labelled horizontal bar of the same map;
* :func:`to_uint8` turns an image in [0, 1] into bytes.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .cameras import Cameras

__all__ = ["BACKGROUND", "DEPTH_SPAN", "PNG_LEVEL", "colour_bar", "depth_display", "depth_normals", "depth_rgb",
           "normal_rgb", "render_layers", "to_uint8", "write_png"]

BACKGROUND = (255, 255, 255)  # RGB of pixels with no surface in depth and normal images
DEPTH_SPAN = 0.5
"""Depth images span ``0 .. DEPTH_SPAN x length_scale`` below the nearest ground-truth point (half the
specimen's diameter: the depth of the hemisphere a view sees)."""


PNG_LEVEL = 1
"""zlib level of the PNGs a run writes (renders, ground truth, depth): 6.5 ms a 288x288 render against 46 ms at
imageio's default 9, for files 12 % larger (benchmarks/png_writes.py)."""


def write_png(path, img: np.ndarray) -> None:
    """Write ``img`` (``[H, W]`` or ``[H, W, 3]`` uint8) as a PNG at :data:`PNG_LEVEL` (through Python, so the write
    guard sees it)."""
    import imageio.v2 as imageio

    imageio.imwrite(path, img, compress_level=PNG_LEVEL)


def to_uint8(img: Tensor) -> np.ndarray:
    """``[H, W, 3]`` in [0, 1] -> uint8 ``[H, W, 3]``."""
    return (img.detach().clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)


def depth_normals(cams: Cameras, depth: Tensor) -> Tensor:
    """World normals ``[C, H, W, 3]`` of depth maps ``[C, H, W]`` (central differences of the
    unprojected points, facing the camera); zero where a neighbour is missing."""
    pts = cams.unproject(depth)
    dx = torch.zeros_like(pts)
    dy = torch.zeros_like(pts)
    dx[:, :, 1:-1] = pts[:, :, 2:] - pts[:, :, :-2]
    dy[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    n = torch.nn.functional.normalize(torch.cross(dy, dx, dim=-1), dim=-1)
    facing = (n * cams.forward[:, None, None, :].to(n)).sum(-1, keepdim=True)
    return torch.where(facing > 0, -n, n)


def render_layers(backbone, cams: Cameras, alpha_min: float = 0.5, normals: bool = True) -> dict[str, Tensor]:
    """Render ``cams`` (no gradients): ``rgb [C,H,W,3]``, ``depth [C,H,W]``, ``valid [C,H,W]`` bool,
    ``alpha [C,H,W]`` and, with ``normals``, world ``normal [C,H,W,3]`` (unit, zero where invalid)."""
    with torch.no_grad():
        out = backbone.render(cams)
    depth = out.get("median_depth", out["depth"])[..., 0].float()
    alpha = out["alpha"][..., 0].float() if "alpha" in out else torch.ones_like(depth)
    valid = (alpha >= alpha_min) & torch.isfinite(depth) & (depth > 0 if not cams.is_ortho else True)
    layers = {"rgb": out["rgb"].float().clamp(0, 1), "depth": depth, "valid": valid, "alpha": alpha}
    if normals:
        n = out.get("normal")
        n = torch.nn.functional.normalize(n.float(), dim=-1) if n is not None else depth_normals(
            cams.to(device=depth.device, dtype=depth.dtype), torch.where(valid, depth, torch.zeros_like(depth)))
        layers["normal"] = torch.where(valid[..., None], n, torch.zeros_like(n))
    return {k: v.detach().cpu() for k, v in layers.items()}


def depth_rgb(depth: Tensor, valid: Tensor, lo: float | None = None, hi: float | None = None,
              background: tuple[int, int, int] = BACKGROUND) -> np.ndarray:
    """Depth ``[H, W]`` -> uint8 RGB ``[H, W, 3]`` (turbo; ``lo`` red .. ``hi`` blue; default: the valid range)."""
    import cv2

    d = depth.detach().cpu().double().numpy()
    v = valid.detach().cpu().numpy().astype(bool) & np.isfinite(d)
    out = np.empty((*d.shape, 3), np.uint8)
    out[:] = background
    if not v.any():
        return out
    lo = float(d[v].min()) if lo is None else lo
    hi = float(d[v].max()) if hi is None else hi
    x = 1.0 - np.clip((d - lo) / max(hi - lo, 1e-12), 0, 1)  # near -> 1 -> red end of turbo
    mapped = cv2.applyColorMap((x * 255 + 0.5).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    out[v] = mapped[v]
    return out


def depth_display(depth: Tensor, gt: Tensor | None, mask: Tensor | None,
                  valid: Tensor, span: float) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Depth ``[H, W]`` (and its ground truth) as images that compare: turbo colour map of the depth
    below the nearest ground-truth point, ``0 .. span`` scene units (near red, far blue).

    Both images show the same pixels: the ground truth's (``gt > 0`` inside ``mask``) where there is a
    ground truth, else the render's ``valid`` ones. Returns ``(render, gt or None, lo)`` with ``lo``
    the depth shown as 0.
    """
    shown = valid.bool() if gt is None else (gt > 0) & (mask.bool() if mask is not None else True)
    ref = depth if gt is None else gt
    lo = float(ref[shown].min()) if bool(shown.any()) else 0.0
    pred = depth_rgb(depth, shown & torch.isfinite(depth), lo, lo + span)
    return pred, (None if gt is None else depth_rgb(gt, shown, lo, lo + span)), lo


def normal_rgb(normal: Tensor, cams: Cameras, valid: Tensor | None = None,
               background: tuple[int, int, int] = BACKGROUND) -> np.ndarray:
    """World normals ``[H, W, 3]`` of one camera ``cams`` -> uint8 RGB of the camera-space normal."""
    R = cams.world_to_cam[0, :3, :3].to(normal)
    n = normal @ R.T * normal.new_tensor([1.0, -1.0, -1.0])
    img = to_uint8(n * 0.5 + 0.5)
    v = (normal.norm(dim=-1) > 0) if valid is None else valid.bool()
    img[~v.cpu().numpy()] = background
    return img


def colour_bar(lo: float, hi: float, unit: str, width: int = 360, label: str = "depth") -> np.ndarray:
    """uint8 RGB ``[52, width, 3]``: the turbo bar of :func:`depth_rgb` from ``lo`` (near) to ``hi`` (far)."""
    import cv2

    bar_h, pad = 16, 8
    img = np.full((52, width, 3), 255, np.uint8)
    x = 1.0 - np.linspace(0, 1, width - 2 * pad)
    row = cv2.applyColorMap((x * 255 + 0.5).astype(np.uint8)[None], cv2.COLORMAP_TURBO)[0, :, ::-1]
    img[4:4 + bar_h, pad:width - pad] = row[None]
    font, col = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)
    for frac in (0.0, 0.5, 1.0):
        val = lo + frac * (hi - lo)
        text = f"{val:.3g}"
        xpos = pad + int(frac * (width - 2 * pad - 1))
        cv2.line(img, (xpos, 4 + bar_h), (xpos, 4 + bar_h + 4), col, 1)
        (tw, _), _ = cv2.getTextSize(text, font, 0.4, 1)
        cv2.putText(img, text, (min(max(xpos - tw // 2, 0), width - tw), 36), font, 0.4, col, 1, cv2.LINE_AA)
    caption = f"{label} [{unit}]  (near = red, far = blue)"
    cv2.putText(img, caption, (pad, 49), font, 0.38, col, 1, cv2.LINE_AA)
    return img
