"""Render one view of the synthetic scene: ray casting, ground-truth maps and SEM/colour shading.

Depth, masks and normals are sampled at pixel centres (no anti-aliasing), so the mask is exactly
``depth > 0``. Grey and colour images take the centre sample, and pixels on a silhouette (the hit
class or the depth changes within the 3x3 neighbourhood) are re-rendered with ``s x s``
sub-samples and averaged (adaptive anti-aliasing; ``supersample = 1`` turns it off).
The substrate (if any) is shaded but is not part of the specimen: its depth, normal and mask are 0.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..cameras import Cameras
from .albedo import BACKGROUND_RGB, SUBSTRATE_ALBEDO, colorize
from .sdf import Grain  # or any specimen with the same attributes (e.g. diatom.Diatom)
from .shading import DETECTOR_CAM, ShadingConfig, detector_shadow, ellipsoid_shadow, sem_grey
from .texture import texture_gain
from .trace import ray_sphere, sdf_gradient, sphere_trace

__all__ = ["RenderConfig", "ViewImages", "cast", "cast_and_shade", "render_views", "view_rays"]

BG, GRAIN, SUBSTRATE = 0, 1, 2


@dataclass
class RenderConfig:
    """How views are rendered (float32 tracing, float64 ray set-up)."""

    supersample: int = 2          # s x s sub-samples on silhouette pixels; 1 = off
    substrate: bool = True
    max_steps: int = 64
    tol: float = 1e-4             # |SDF| at accepted hits, in units of the grain size
    chunk: int = 1 << 20          # rays per chunk (bounds memory at any resolution)
    texture: float = 0.0          # surface texture amplitude (arcsem.synthetic.texture; 0 = none)
    texture_scale: float = 0.05   # its coarsest lattice spacing, in units of the specimen's size
    texture_seed: int = 0
    shading: ShadingConfig = field(default_factory=ShadingConfig)


@dataclass
class ViewImages:
    """Outputs of one view (``H x W``): float32 ``depth``, ``normal [H,W,3]``, ``grey``, ``color
    [H,W,3]``, bool ``mask``, and the specimen's hit points ``points [M, 3]`` with grey ``point_grey [M]``."""

    depth: Tensor
    mask: Tensor
    normal: Tensor
    grey: Tensor
    color: Tensor
    points: Tensor
    point_grey: Tensor


def view_rays(cams: Cameras, uvs: list[Tensor]) -> dict[str, Tensor]:
    """Rays of view ``i`` through pixels ``uvs[i] [N_i, 2]`` (float64), concatenated over views.

    Returns origins ``o``, unit directions ``u`` ``[N, 3]``, ``norm [N]`` (|direction| of
    ``Cameras.rays``, so that z-depth = distance / norm) and the detector direction ``det [N, 3]``.
    """
    out = {"o": [], "u": [], "norm": [], "det": []}
    rot = cams.cam_to_world[:, :3, :3]
    det_cam = torch.tensor(DETECTOR_CAM, dtype=torch.float64)
    for i, uv in enumerate(uvs):
        o, d = cams[i].rays(uv[None])
        norm = d[0].norm(dim=-1)
        out["o"].append(o[0])
        out["u"].append(d[0] / norm[:, None])
        out["norm"].append(norm)
        out["det"].append(torch.nn.functional.normalize(rot[i] @ det_cam, dim=0).expand(len(uv), 3))
    return {k: torch.cat(v) for k, v in out.items()}


def cast(g: Grain, o: Tensor, u: Tensor, cfg: RenderConfig) -> tuple[Tensor, Tensor]:
    """Hit class ``[N]`` (0 background, 1 grain, 2 substrate) and distance ``[N]`` (float64,
    ``inf`` on background) of unit rays ``o, u [N, 3]`` (float64); ``g`` is float32."""
    t0, t1, inside = ray_sphere(o, u, g.bound_radius)
    kind = torch.zeros(len(o), dtype=torch.long)
    t = torch.full((len(o),), float("inf"), dtype=torch.float64)
    idx = inside.nonzero()[:, 0]
    if idx.numel():
        start = (o[idx] + t0[idx, None] * u[idx]).float()
        s, hit = sphere_trace(g.sdf, start, u[idx].float(), (t1 - t0)[idx].float(), max_steps=cfg.max_steps,
                              eps=0.5 * cfg.tol * g.size, tol=cfg.tol * g.size)
        kind[idx[hit]] = GRAIN
        t[idx[hit]] = t0[idx[hit]] + s[hit].double()
    if cfg.substrate:
        tp = (g.substrate_z - o[:, 2]) / u[:, 2].clamp(max=-1e-12)
        plane = (u[:, 2] < 0) & (tp > 0) & (tp < t)
        kind[plane] = SUBSTRATE
        t = torch.where(plane, tp, t)
    return kind, t


def shade(g: Grain, kind: Tensor, pts: Tensor, u: Tensor, det: Tensor, cfg: RenderConfig) -> dict[str, Tensor]:
    """Grey ``[N]``, colour ``[N, 3]`` and specimen normals ``[N, 3]`` of cast rays (float32 ``g``)."""
    n = len(kind)
    grey = torch.full((n,), cfg.shading.background, dtype=torch.float32)
    color = torch.tensor(BACKGROUND_RGB, dtype=torch.float32).repeat(n, 1)
    normal = torch.zeros(n, 3, dtype=torch.float32)
    for cls in (GRAIN, SUBSTRATE):
        idx = (kind == cls).nonzero()[:, 0]
        if idx.numel() == 0:
            continue
        p, uu, dd = pts[idx].float(), u[idx].float(), det[idx].float()
        if cls == GRAIN:
            # Normals and curvature from a float64 stencil: in float32 the rounding of the SDF
            # (~1e-7) divided by h^2 = 4e-6 put per-pixel noise of up to 0.17 into the grey level
            # (a stipple no view-consistent model can reproduce). Tracing stays float32.
            nrm, lap = (x.float() for x in sdf_gradient(g.to(torch.float64).sdf, pts[idx].double()))
            albedo = g.albedo(p)
            gain = 1.0
            normal[idx] = nrm
        else:
            nrm = torch.tensor([0.0, 0.0, 1.0]).expand_as(p)
            lap = torch.zeros(len(p))
            albedo = torch.tensor(getattr(g, "substrate_albedo", SUBSTRATE_ALBEDO)).expand_as(p)  # parts: its own
            gain = cfg.shading.substrate_gain
        vis = detector_shadow(g.sdf, p, nrm, dd) if cls == GRAIN else ellipsoid_shadow(p, dd, g.radii)
        gr = gain * sem_grey(nrm, uu, dd, lap, vis, cfg.shading)
        if cfg.texture:
            tex = texture_gain(pts[idx], cfg.texture, cfg.texture_scale * g.size, cfg.texture_seed + cls)
            gr = (gr * tex).clamp(0, 1)
        grey[idx] = gr
        color[idx] = colorize(albedo, gr)
    return {"grey": grey, "color": color, "normal": normal}


def cast_and_shade(g: Grain, rays: dict[str, Tensor], cfg: RenderConfig, progress=None) -> dict[str, Tensor]:
    """Cast and shade ``rays`` (from :func:`view_rays`) in chunks of ``cfg.chunk``.

    Returns ``kind [N]``, world ``points [N, 3]`` (float64), z-``depth [N]`` (float64, 0 off the
    specimen), ``grey [N]``, ``color [N, 3]``, ``normal [N, 3]``.
    """
    parts = []
    n = len(rays["o"])
    for i in range(0, n, cfg.chunk):
        o, u = rays["o"][i:i + cfg.chunk], rays["u"][i:i + cfg.chunk]
        kind, t = cast(g, o, u, cfg)
        pts = o + torch.where(torch.isfinite(t), t, torch.zeros_like(t))[:, None] * u
        out = shade(g, kind, pts, u, rays["det"][i:i + cfg.chunk], cfg)
        depth = torch.where(kind == GRAIN, t / rays["norm"][i:i + cfg.chunk], torch.zeros_like(t))
        parts.append({"kind": kind, "points": pts, "depth": depth, **out})
        if progress is not None:
            progress.update(len(o))
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def _edges(kind: Tensor, depth: Tensor, jump: float) -> Tensor:
    """``[C, H, W]`` bool: the hit class or depth (beyond ``jump``) changes in the 3x3 neighbourhood."""
    k = torch.nn.functional.pad(kind[:, None].float(), (1, 1, 1, 1), mode="replicate")
    z = torch.nn.functional.pad(depth[:, None].float(), (1, 1, 1, 1), mode="replicate")
    pool = lambda x: torch.nn.functional.max_pool2d(x, 3, 1)[:, 0]
    return (pool(k) != -pool(-k)) | (pool(z) + pool(-z) > jump)


def _subsamples(uv: Tensor, s: int) -> Tensor:
    """``[N * s * s, 2]`` sub-pixel positions (``s x s`` grid) of pixel centres ``uv [N, 2]``."""
    off = (torch.arange(s, dtype=torch.float64) + 0.5) / s - 0.5
    oy, ox = torch.meshgrid(off, off, indexing="ij")
    return (uv[:, None, :] + torch.stack([ox, oy], -1).reshape(1, -1, 2)).reshape(-1, 2)


def render_views(g: Grain, cams: Cameras, cfg: RenderConfig, progress: bool = False) -> list[ViewImages]:
    """Render every camera of ``cams`` (float64, ``C`` views of ``H x W``); ``g`` float64 or float32.

    All ``C * H * W`` rays are traced together (in chunks of ``cfg.chunk``): batching views keeps
    the per-call overhead of the many small tensor ops low. Results are held for all ``C`` views,
    so callers render large images a few views at a time.
    """
    g32 = g.to(torch.float32)
    C, H, W = len(cams), cams.height, cams.width
    uv = cams.pixel_grid(torch.float64).reshape(-1, 2)
    bar = _bar(progress, C * H * W)
    res = cast_and_shade(g32, view_rays(cams, [uv] * C), cfg, bar)
    kind, depth = res["kind"].reshape(C, H, W), res["depth"].reshape(C, H, W)
    grey, color = res["grey"].reshape(C, H * W), res["color"].reshape(C, H * W, 3)
    s = cfg.supersample
    edge = _edges(kind, depth, 0.05 * g.size).reshape(C, -1)
    if s > 1 and edge.any():
        eidx = [e.nonzero()[:, 0] for e in edge]
        sub = cast_and_shade(g32, view_rays(cams, [_subsamples(uv[e], s) for e in eidx]), cfg)
        start = 0
        for i, e in enumerate(eidx):
            n = len(e) * s * s
            grey[i, e] = sub["grey"][start:start + n].reshape(-1, s * s).mean(1)
            color[i, e] = sub["color"][start:start + n].reshape(-1, s * s, 3).mean(1)
            start += n
    if bar is not None:
        bar.close()
    pts, normal = res["points"].reshape(C, H * W, 3), res["normal"].reshape(C, H, W, 3)
    mask = kind == GRAIN
    return [
        ViewImages(depth=depth[i].float(), mask=mask[i], normal=normal[i], grey=grey[i].reshape(H, W),
                   color=color[i].reshape(H, W, 3), points=pts[i][mask[i].reshape(-1)].float(),
                   point_grey=grey[i][mask[i].reshape(-1)])
        for i in range(C)
    ]


def _bar(show: bool, total: int):
    if not show:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="ray", desc="synthetic scene", leave=False)
