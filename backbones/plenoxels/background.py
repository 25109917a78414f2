"""What rays see outside the grid's box: Plenoxels' background models (``background_model``).

A model returns, per ray ``[R]``, a premultiplied layer in front of the grid ``front [R, 4]`` (rgb, alpha;
zero for models without one) and a colour behind it ``back [R, 3]``; the backbone composites
``front + (1 - front_alpha) (grid + (1 - grid_alpha) back)``. ACT (when on) transforms these colours as
it does the grid's samples. Three models:

* ``constant`` (svox2's default): one colour, learned or fixed (``learn_background``).
* ``plane`` (our SEM model): the specimen lies on a flat stub. A textured plane through the bottom of the
  box, facing the cameras (:func:`plane_normal`: the stage's vertical of the orbit frame when the views
  look down on its plane, else the cameras' mean backward direction), holds SH coefficients of degree
  ``background_sh_degree`` per texel
  (the substrate's brightness changes with the view in SEM: tilt, detector shadow); texture coordinates
  are contracted (``s = x / (|x| + c)``, ``c`` the box's half-size) so that texels are fine under the
  specimen and coarse towards the horizon, which grazing views see. Rays that miss the plane see the
  constant.
* ``msi`` (svox2's multi-sphere image, for a camera outside it): ``background_layers`` spheres around the
  box, radii evenly spaced in inverse radius from the box's half-diagonal to ``msi_far`` times it, each an
  equirectangular image of colour and opacity. A ray crosses a sphere twice: the near crossings are
  composited in front of the grid, the far ones behind it, then the constant. Its poles lie on the stage's
  horizontal axis across the views, away from what the cameras see.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..sh import sh_basis

__all__ = ["Background", "ConstantBackground", "MSIBackground", "PlaneBackground", "build_background", "plane_normal"]

MIN_ELEVATION_DEG = 5.0
"""The views must see the stage vertical's plane at least this high on average for the plane to lie in it."""


class Background(nn.Module):
    """Base: a learned or fixed constant colour (what every model shows where it has nothing)."""

    def __init__(self, color: list[float], learn: bool):
        super().__init__()
        value = torch.tensor(color, dtype=torch.float32)
        if learn:  # a logit (kept inside (0, 1)); a fixed colour is kept as given
            self.const_logit = nn.Parameter(torch.logit(value.clamp(0.01, 0.99)))
        else:
            self.register_buffer("const_value", value)

    def constant(self) -> Tensor:
        """``[3]`` colour."""
        return torch.sigmoid(self.const_logit) if hasattr(self, "const_logit") else self.const_value

    def forward(self, rays_o: Tensor, rays_d: Tensor) -> tuple[Tensor | None, Tensor]:
        """``front [R, 4]`` (premultiplied rgb, alpha; None: nothing in front) and ``back [R, 3]``."""
        return None, self.constant().to(rays_d).expand(rays_d.shape[0], 3)


class ConstantBackground(Background):
    """svox2's background: one colour."""


def _contract(x: Tensor, c: float) -> Tensor:
    return x / (x.abs() + c)


class PlaneBackground(Background):
    """A textured SH plane ``{p: n . p = h}`` (SEM stub) behind the grid; the constant where rays miss it.

    Attributes:
        texture: ``[1, 3 K, N, N]`` SH coefficients (``K = (degree + 1)^2``) per texel, channel-major.
        frame: ``[4, 3]`` buffer: origin on the plane, in-plane axes ``e1``, ``e2``, normal ``n``.
    """

    def __init__(self, bounds: Tensor, normal: Tensor, color: list[float], learn: bool, reso: int, degree: int):
        super().__init__(color, learn)
        n = normal.double() / normal.double().norm()
        e1 = torch.linalg.svd(n[None])[2][-1]
        e2 = torch.linalg.cross(n, e1)
        corners = torch.stack(torch.meshgrid(*[bounds[:, a].double() for a in range(3)], indexing="ij"), -1)
        h = float((corners.reshape(-1, 3) @ n).min())
        centre = bounds.double().mean(0)
        origin = centre - (centre @ n - h) * n
        self.register_buffer("frame", torch.stack([origin, e1, e2, n]).float())
        self.scale = float((bounds[1] - bounds[0]).max() / 2)
        self.degree = degree
        k = (degree + 1) ** 2
        self.texture = nn.Parameter(torch.zeros(1, 3 * k, reso, reso))

    def forward(self, rays_o: Tensor, rays_d: Tensor) -> tuple[Tensor | None, Tensor]:
        origin, e1, e2, n = (v.to(rays_d) for v in self.frame)
        dn = rays_d @ n
        t = ((origin - rays_o) @ n) / torch.where(dn.abs() < 1e-12, torch.full_like(dn, -1e-12), dn)
        hit = (dn < 0) & (t > 0)
        p = rays_o + t.clamp_min(0)[:, None] * rays_d - origin
        uv = torch.stack([_contract(p @ e1, self.scale), _contract(p @ e2, self.scale)], -1)
        uv = torch.where(hit[:, None], uv, torch.zeros_like(uv))
        coef = F.grid_sample(self.texture.to(rays_d), uv[None, :, None, :], mode="bilinear",
                             align_corners=True)[0, :, :, 0].T  # [R, 3K]
        k = (self.degree + 1) ** 2
        basis = sh_basis(self.degree, rays_d / rays_d.norm(dim=-1, keepdim=True)).to(coef)  # [R, K]
        col = torch.relu((basis[:, :, None] * coef.reshape(-1, 3, k).transpose(1, 2)).sum(1) + 0.5)
        return None, torch.where(hit[:, None], col, self.constant().to(col))


class MSIBackground(Background):
    """svox2's multi-sphere image seen from outside: ``L`` spheres of equirectangular colour + opacity.

    Attributes:
        layers: ``[1, 4, L, H, 2H]`` logits of rgb and opacity (bilinear within a layer).
        frame: ``[4, 3]`` buffer: centre, pole axis, and two axes of the equator.
    """

    def __init__(self, bounds: Tensor, up: Tensor, front: Tensor, color: list[float], learn: bool, reso: int,
                 layers: int, far: float):
        super().__init__(color, learn)
        centre = bounds.double().mean(0)
        pole = torch.linalg.cross(up.double(), front.double())
        pole = pole / pole.norm()
        self.register_buffer("frame", torch.stack([centre, pole, front.double(), torch.linalg.cross(pole, front.double())]).float())
        r0 = float((bounds[1] - bounds[0]).norm() / 2) * 1.01
        inv = torch.linspace(1 / r0, 1 / (far * r0), layers, dtype=torch.float64)
        self.register_buffer("radii", (1 / inv).float())  # inner to outer
        data = torch.zeros(1, 4, layers, max(2, reso // 2), max(4, reso))
        data[:, 3] = -4.0  # opacity 0.018: transparent at the start
        self.layers = nn.Parameter(data)

    def _sample(self, pts: Tensor) -> Tensor:
        """``[R, L, 4]`` (rgb, opacity) of points ``[R, L, 3]`` on layer ``l`` of each slot."""
        c, pole, a, b = (v.to(pts) for v in self.frame)
        q = pts - c
        lat = torch.asin((q @ pole / q.norm(dim=-1).clamp_min(1e-12)).clamp(-1, 1)) / (math.pi / 2)
        lon = torch.atan2(q @ b, q @ a) / math.pi
        L = self.radii.shape[0]
        z = torch.linspace(-1, 1, L, dtype=pts.dtype, device=pts.device).expand_as(lat)
        grid = torch.stack([lon, lat, z], -1)[None, :, :, None, :]  # [1, R, L, 1, 3]
        val = F.grid_sample(self.layers.to(pts), grid, mode="bilinear", align_corners=True)  # [1, 4, R, L, 1]
        return torch.sigmoid(val[0, :, :, :, 0].permute(1, 2, 0))

    def forward(self, rays_o: Tensor, rays_d: Tensor) -> tuple[Tensor | None, Tensor]:
        c = self.frame[0].to(rays_d)
        r = self.radii.to(rays_d)
        dd = (rays_d * rays_d).sum(-1, keepdim=True)
        bq = ((rays_o - c) * rays_d).sum(-1, keepdim=True) / dd  # [R, 1]
        cq = (((rays_o - c) ** 2).sum(-1, keepdim=True) - r**2) / dd  # [R, L]
        disc = bq**2 - cq
        hit = disc > 0
        root = torch.sqrt(disc.clamp_min(0))
        t_near, t_far = -bq - root, -bq + root
        near = self._sample(rays_o[:, None] + t_near[..., None] * rays_d[:, None])
        far = self._sample(rays_o[:, None] + t_far[..., None] * rays_d[:, None])
        a_near = torch.where(hit & (t_near > 0), near[..., 3], torch.zeros_like(t_near))
        a_far = torch.where(hit & (t_far > 0), far[..., 3], torch.zeros_like(t_far))
        # front: outer to inner (reverse the layer order); back: inner to outer, then the constant
        fa = a_near.flip(1)
        ft = torch.cumprod(torch.cat([torch.ones_like(fa[:, :1]), 1 - fa[:, :-1]], 1), 1)
        fw = ft * fa
        front = torch.cat([(fw[..., None] * near[..., :3].flip(1)).sum(1), fw.sum(1, keepdim=True)], -1)
        bt = torch.cumprod(torch.cat([torch.ones_like(a_far[:, :1]), 1 - a_far[:, :-1]], 1), 1)
        bw = bt * a_far
        rest = (bt[:, -1] * (1 - a_far[:, -1]))[:, None]
        back = (bw[..., None] * far[..., :3]).sum(1) + rest * self.constant().to(rays_d)
        return front, back


def plane_normal(cameras, up: Tensor) -> Tensor:
    """``[3]`` unit normal of the substrate plane, towards ``cameras``.

    The stage's vertical ``up [3]`` (:func:`arcsem.orbit.orbit_frame`: the direction most orthogonal to the
    image-right axes) when the views see the plane normal to it at a mean elevation of at least
    ``MIN_ELEVATION_DEG`` (cameras circling the specimen above its stub, the built-in scene's arcs), signed
    towards them. Otherwise the cameras' mean backward direction: in a tilt series about an in-image axis the
    right axes turn about the tilt axis (or stay on it), so ``up`` lies in the substrate plane, which every
    view would see edge-on; an SEM looks down on its stub, and the series' views gather about its normal.
    """
    back = -cameras.forward.double()
    back = back / back.norm(dim=-1, keepdim=True)
    up = up.double() / up.double().norm()
    sin_el = float((back @ up).mean())
    if abs(sin_el) >= math.sin(math.radians(MIN_ELEVATION_DEG)):
        return up if sin_el > 0 else -up
    mean = back.mean(0)
    return mean / mean.norm()


def build_background(cfg, bounds: Tensor, cameras=None) -> Background:
    """The background model of a :class:`~.config.PlenoxelsConfig` for a grid over ``bounds [2, 3]``."""
    kind = cfg.background_model
    if kind == "constant":
        return ConstantBackground(list(cfg.background), cfg.learn_background)
    from arcsem.orbit import orbit_frame

    if cameras is not None:
        frame = orbit_frame(cameras, bounds)
        up, front = frame.up, frame.front
    else:
        up, front = torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, -1.0, 0.0])
    if kind == "plane":
        normal = plane_normal(cameras, up) if cameras is not None else up
        return PlaneBackground(bounds, normal, list(cfg.background), cfg.learn_background, cfg.background_reso,
                               cfg.background_sh_degree)
    return MSIBackground(bounds, up, front, list(cfg.background), cfg.learn_background, cfg.background_reso,
                         cfg.background_layers, cfg.msi_far)
