"""``backbone.rasterizer=gsplat``: gsplat's CUDA rasterisers (nerfstudio) for 3DGS and 2DGS, optional.

Used only where gsplat is installed (``pip install gsplat``; it compiles its CUDA code on first use) and
the model is on a CUDA device; anywhere else the choice is a one-line ConfigError. Our model still computes
the colours (SH + ACT, the PyTorch path) and gsplat gets them decoded (``sh_degree=None``), so ACT, the
densification statistics (read from the 3-D means' gradient) and every loss are unchanged.

How our conventions map (checked on the CPU against gsplat's own PyTorch projection in
tests/test_gsplat_bridge.py; the rendered images and their gradients there too, CUDA-marked, and whole runs in
tests/test_cuda.py, both on a GPU only):

* cameras: ``world_to_cam`` -> ``viewmats`` (both OpenCV axes), ``K`` -> ``Ks``; pinhole -> ``pinhole``,
  orthographic -> ``ortho`` (3DGS only: gsplat's 2DGS is pinhole only). gsplat's Jacobian has no skew term,
  so a skewed ``K`` is refused;
* splats: quaternions ``(w, x, y, z)`` as ours; 2DGS scales get a third axis of 1 (gsplat's CUDA 2DGS reads only
  the first two and takes the normal from ``R diag(s0, s1, 1)``); opacities after the sigmoid;
* outputs: ``rgb``, ``alpha``, ``depth`` = expected camera ``z`` (``sum w z / alpha``), ``radii`` the larger of
  gsplat's per-axis radii, ``visible = radii > 0``, ``means2d`` gsplat's screen positions (pixels).

Where gsplat differs from our rasterisers (not mapped; the CUDA test keeps its scene clear of them):
alpha is clamped at 0.999 (ours 0.99, the official value); the 3DGS Jacobian is evaluated at the centre
clamped to 1.3x the view frustum (as the official code); footprints are 3.33 sigma per axis (ours 3 sigma);
the 2DGS depth channels (expected and median depth, distortion) use each splat's centre depth, not the depth
where the ray meets the splat; its low-pass filter is centred on the centre of the splat's projected 1-sigma ellipse (as the official
code; ours on the projected splat centre: the two differ under perspective where the filter wins, i.e. for splats
narrower than the filter) and compiled in at the official ``lowpass_sigma=1/sqrt(2)`` (the
quick preset's 2DGS value, 1/sqrt(8), composes to it on gsplat: conf/tuning/quick_gs2d.yaml); its 2DGS backward
launches on tiles of at most 16 px (:func:`require_2dgs_tile`). gsplat would also draw 2-D splats whose 3-sigma
disk crosses the camera plane, which ours culls; the bridge culls them too (:func:`drawn_2dgs`), by handing them
to gsplat at the camera's centre, where its projection drops them before any arithmetic (:func:`culled_at_eye`).
"""
from __future__ import annotations

import torch
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.errors import ConfigError
from arcsem.rotations import quat_to_rotmat

from .config import LOWPASS_SIGMA

__all__ = ["culled_at_eye", "drawn_2dgs", "gsplat_cameras", "render_gsplat_2dgs", "render_gsplat_3dgs", "require_2dgs_tile",
           "require_gsplat", "require_lowpass"]

KEY = "backbone.rasterizer"


def require_gsplat(device) -> None:
    """ConfigError unless gsplat imports and ``device`` is a CUDA device."""
    if str(device).split(":")[0] != "cuda":
        raise ConfigError(f"{KEY}=gsplat needs the model on a CUDA device (device=cuda), not '{device}'; "
                          f"use {KEY}=auto")
    try:
        import gsplat  # noqa: F401
    except ImportError as e:
        raise ConfigError(f"{KEY}=gsplat needs the gsplat package (pip install gsplat): {e}") from None


def require_lowpass(lowpass_sigma: float) -> None:
    """ConfigError unless the 2DGS low-pass sigma is gsplat's fixed one (``1/sqrt(2)`` px, the official)."""
    if abs(lowpass_sigma - LOWPASS_SIGMA) > 1e-9:
        raise ConfigError(f"{KEY}=gsplat: gsplat's low-pass filter is fixed at backbone.lowpass_sigma=0.7071 "
                          f"(got {lowpass_sigma}); use {KEY}=auto")


def require_2dgs_tile(tile: int) -> None:
    """ConfigError unless gsplat's 2DGS can launch on ``tile``-px tiles: a tile is one CUDA block of ``tile^2``
    threads, a block holds at most 65,536 registers, and gsplat's 2DGS backward kernel needs more than the 64 per
    thread that 1024 threads (32-px tiles) would leave: it fails with "too many resources requested for launch"
    (seen on an H200, benchmarks/gpu/gsplat_launch.py; its 3DGS kernels launch at 32 px)."""
    if tile * tile > 256:
        raise ConfigError(f"{KEY}=gsplat: gsplat's 2DGS cannot draw backbone.tile={tile} px tiles (its backward "
                          f"kernel does not launch on blocks of {tile * tile} threads); use backbone.tile=16 or less")


def gsplat_cameras(cams: Cameras, two_d: bool = False) -> tuple[Tensor, Tensor, str]:
    """Our cameras as gsplat's: ``viewmats [C, 4, 4]``, ``Ks [C, 3, 3]`` and its ``camera_model`` name.

    The skew check reads ``K``: it runs where ``K`` is a host tensor (the preflight checks the scene's cameras
    there); on the GPU it would wait for the device at every render."""
    if cams.K.device.type == "cpu" and bool((cams.K[:, 0, 1] != 0).any()):
        raise ConfigError(f"{KEY}=gsplat: the cameras have a skewed K (K[0, 1] != 0), which gsplat's projection "
                          f"ignores; use {KEY}=auto")
    if cams.is_ortho and two_d:
        raise ConfigError(f"{KEY}=gsplat: gsplat's 2DGS has no orthographic camera; use {KEY}=auto")
    return cams.world_to_cam.contiguous(), cams.K.contiguous(), "ortho" if cams.is_ortho else "pinhole"


def _background(background: Tensor | None, rgb: Tensor, alpha: Tensor) -> Tensor:
    return rgb if background is None else rgb + (1 - alpha) * background.to(rgb)


def _screen(meta: dict) -> tuple[Tensor, Tensor, Tensor]:
    """radii ``[C, N]`` long (the larger axis), visible ``[C, N]``, means2d ``[C, N, 2]`` (its grad retained)."""
    radii = meta["radii"]
    radii = radii.amax(-1) if radii.ndim == 3 else radii  # gsplat >= 1.5: per-axis radii [C, N, 2]
    means2d = meta["means2d"]
    if means2d.requires_grad:
        means2d.retain_grad()
    return radii.long(), radii > 0, means2d


def _colors(colors: Tensor, C: int, N: int) -> Tensor:
    return (colors.expand(C, N, 3) if colors.ndim == 2 else colors).contiguous()


def render_gsplat_3dgs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                       cams: Cameras, *, background: Tensor | None = None, tile: int = 16, near: float = 0.01,
                       **_: object) -> dict[str, Tensor]:
    """:func:`arcsem.backbones.gs3d.render.render_3dgs` on ``gsplat.rasterization`` (same arguments and outputs:
    rgb ``[C, H, W, 3]``, alpha and depth ``[C, H, W, 1]``, radii/visible ``[C, N]``, means2d ``[C, N, 2]``)."""
    from gsplat import rasterization

    C, N = len(cams), means.shape[0]
    viewmats, Ks, model = gsplat_cameras(cams.to(dtype=means.dtype))
    out, alpha, meta = rasterization(
        means, quats, scales, opacities, _colors(colors, C, N), viewmats, Ks, cams.width, cams.height,
        near_plane=near, eps2d=0.3, packed=False, tile_size=tile, render_mode="RGB+ED",
        rasterize_mode="classic", camera_model=model)
    radii, visible, means2d = _screen(meta)
    return {"rgb": _background(background, out[..., :3], alpha), "alpha": alpha, "depth": out[..., 3:4],
            "radii": radii, "visible": visible, "means2d": means2d}


def render_gsplat_2dgs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                       cams: Cameras, *, background: Tensor | None = None, tile: int = 16, near: float = 0.01,
                       dist_depth: tuple[float, float, float] = (0.0, 1.0, 0.0), lowpass_sigma: float = LOWPASS_SIGMA,
                       **_: object) -> dict[str, Tensor]:
    """:func:`arcsem.backbones.gs2d.render.render_2dgs` on ``gsplat.rasterization_2dgs`` (pinhole cameras).

    The depth outputs come from extra channels, not gsplat's own distortion (an L1 spread, where 2DGS's is
    squared): gsplat composites ``m' = m - m_c`` and ``m'^2`` after the colours and appends the centre depth
    ``z`` (``render_mode="RGB+D"``; its median reads that last channel), with ``m = c0 + c1 z + c2 / z``
    (``dist_depth``) and ``m_c`` each camera's median ``m`` (the distortion does not depend on it; it keeps the
    moments small in float32). Distortion = ``alpha M2 - M1^2`` = 2DGS's ``sum_{i<j} w_i w_j (m_i - m_j)^2``.
    Outputs as render_2dgs: rgb, alpha, depth, median_depth, distortion, normal (world, ``sum w n``), radii,
    visible, means2d.
    """
    require_lowpass(lowpass_sigma)
    require_2dgs_tile(tile)
    if len(cams) > 1:  # per camera: the culled splats differ between cameras (gsplat takes one opacity per splat)
        outs = [render_gsplat_2dgs(means, quats, scales, opacities, colors if colors.ndim == 2 else colors[i:i + 1],
                                   cams[i:i + 1], background=background, tile=tile, near=near,
                                   dist_depth=dist_depth, lowpass_sigma=lowpass_sigma) for i in range(len(cams))]
        return {k: torch.cat([o[k] for o in outs]) for k in outs[0]}
    return _render_gsplat_2dgs_one(means, quats, scales, opacities, colors, cams, background, tile, near, dist_depth)


def drawn_2dgs(means: Tensor, quats: Tensor, scales: Tensor, world_to_cam: Tensor, near: float) -> Tensor:
    """``[C, N]`` bool: the splats our 2DGS rasteriser draws (:func:`footprint_2dgs`): centre depth above ``near``
    and the 3-sigma disk wholly in front of the camera plane (``9 (z_u^2 s_0^2 + z_v^2 s_1^2) < z_c^2``, its image an
    ellipse). gsplat draws a splat whose disk crosses that plane too; there its screen centre divides by a
    quantity near zero, and its gradient blows up the splat's position."""
    R = quat_to_rotmat(quats.detach())  # [N, 3, 3]
    zrow = world_to_cam[:, 2, :3].to(R)  # [C, 3]
    zu, zv = zrow @ R[:, :, 0].T, zrow @ R[:, :, 1].T  # [C, N]
    zc = zrow @ means.detach().T + world_to_cam[:, 2, 3:4].to(R)
    s = scales.detach()
    return (zc > near) & (9 * ((zu * s[:, 0]) ** 2 + (zv * s[:, 1]) ** 2) < zc ** 2)


def culled_at_eye(means: Tensor, drawn: Tensor, world_to_cam: Tensor) -> Tensor:
    """``[N, 3]``: ``means`` where ``drawn`` (``[N]``), else the centre of the camera ``world_to_cam`` (``[4, 4]``).

    gsplat's 2DGS projection drops a splat whose camera depth is at most ``near_plane`` before computing anything
    else, and its backward skips dropped splats. A splat given only opacity 0 is still projected and
    differentiated, and where its disk crosses the camera plane the projection divides by about zero (its
    ``distance``); a splat at the eye (depth 0) is dropped first. The gradient of a culled row is zero, as in ours.
    """
    R, t = world_to_cam[:3, :3].to(means), world_to_cam[:3, 3].to(means)
    eye = -(R.T @ t)  # [3]
    return torch.where(drawn[:, None], means, eye)


def _render_gsplat_2dgs_one(means, quats, scales, opacities, colors, cams, background, tile, near, dist_depth):
    from gsplat import rasterization_2dgs

    C, N = len(cams), means.shape[0]
    viewmats, Ks, _ = gsplat_cameras(cams.to(dtype=means.dtype), two_d=True)
    c0, c1, c2 = dist_depth
    z = torch.einsum("cj,nj->cn", viewmats[:, 2, :3], means) + viewmats[:, 2, 3:4]  # [C, N] centre depth
    m = c0 + c1 * z + c2 / z.clamp_min(near)
    m = m - m.detach().median(-1, keepdim=True).values
    feats = torch.cat([_colors(colors, C, N), m[..., None], m[..., None] ** 2], -1)  # [C, N, 5]
    scales3 = torch.cat([scales, torch.ones_like(scales[:, :1])], -1)  # the third is not read (module doc)
    drawn = drawn_2dgs(means, quats, scales, cams.world_to_cam, near)  # [1, N]
    out, alpha, normal, _, _, median, meta = rasterization_2dgs(
        culled_at_eye(means, drawn[0], cams.world_to_cam[0]), quats, scales3, opacities * drawn[0], feats,
        viewmats, Ks, cams.width, cams.height, near_plane=near,
        packed=False, tile_size=tile, render_mode="RGB+D")
    depth = torch.where(alpha > 0, out[..., 5:6] / alpha.clamp_min(1e-10), torch.zeros_like(alpha))
    dist = (alpha * out[..., 4:5] - out[..., 3:4] ** 2).clamp_min(0)
    radii, visible, means2d = _screen(meta)
    radii, visible = radii * drawn, visible & drawn
    return {"rgb": _background(background, out[..., :3], alpha), "alpha": alpha, "depth": depth,
            "median_depth": median, "distortion": dist, "normal": normal, "radii": radii, "visible": visible,
            "means2d": means2d}
