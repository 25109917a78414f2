"""An analytic test scene for the colourisation code: an ellipsoid seen by look-at cameras.

Depth comes from a closed-form ray/ellipsoid intersection (no rendering), colours from a smooth
function of the 3-D point, so the pseudo-colour of any pixel has a known answer. Used by the tests
and by ``benchmarks/bench_pseudocolor.py``.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from ..cameras import Cameras, look_at

__all__ = ["arc_cameras", "ellipsoid_depth", "point_color"]


def arc_cameras(n: int, width: int, height: int, model: str = "pinhole", dist: float = 4.0,
                fov_deg: float = 40.0, ortho_extent: float = 3.0) -> Cameras:
    """``n`` cameras: about 2/3 on a horizontal arc (-60..60 deg), the rest on a vertical arc up to 75 deg."""
    nh = max(1, round(n * 0.625))
    nv = n - nh
    az = torch.linspace(-60, 60, nh).tolist()
    el = torch.linspace(10, 75, nv).tolist() if nv else []
    eyes = []
    for a in az:
        a = math.radians(a)
        eyes.append([dist * math.sin(a), 0.0, -dist * math.cos(a)])
    for e in el:
        e = math.radians(e)
        eyes.append([0.0, -dist * math.sin(e), -dist * math.cos(e)])
    eye = torch.tensor(eyes, dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64))
    if model == "pinhole":
        f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    else:
        f = width / ortho_extent
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64).repeat(n, 1, 1)
    return Cameras(w2c.float(), K.float(), width, height, model)


def ellipsoid_depth(cams: Cameras, radii=(1.0, 0.8, 0.9), chunk_rows: int = 256) -> Tensor:
    """z-depth ``[C, H, W]`` float32 of the ellipsoid ``sum((x/r)^2) = 1`` (0 where the ray misses)."""
    r = torch.tensor(radii, dtype=torch.float64)
    out = torch.zeros(len(cams), cams.height, cams.width)
    c64 = cams.to(dtype=torch.float64)
    for r0 in range(0, cams.height, chunk_rows):
        rows = min(chunk_rows, cams.height - r0)
        ys, xs = torch.meshgrid(torch.arange(r0, r0 + rows, dtype=torch.float64) + 0.5,
                                torch.arange(cams.width, dtype=torch.float64) + 0.5, indexing="ij")
        uv = torch.stack([xs, ys], -1).reshape(1, -1, 2).expand(len(cams), -1, -1)
        o, d = c64.rays(uv)
        o, d = o / r, d / r
        a, b, c = (d * d).sum(-1), 2 * (o * d).sum(-1), (o * o).sum(-1) - 1
        disc = b * b - 4 * a * c
        t = (-b - disc.clamp_min(0).sqrt()) / (2 * a)
        t = torch.where((disc > 0) & (t > 0), t, torch.zeros_like(t))
        out[:, r0:r0 + rows] = t.reshape(len(cams), rows, cams.width).float()
    return out


def point_color(points: Tensor) -> Tensor:
    """A smooth colour ``[..., 3]`` in [0.1, 0.9] of world points ``[..., 3]``."""
    return 0.5 + 0.4 * torch.sin(2.0 * points + torch.tensor([0.0, 1.0, 2.0], dtype=points.dtype))


def analytic_scene(n_train: int = 8, n_test: int = 2, width: int = 48, height: int = 32, model: str = "pinhole"):
    """A small :class:`arcsem.scene.Scene` of the coloured ellipsoid (grey = channel mean, black background).

    Has ground-truth colours, masks, depths, a point cloud, references for every training view and the
    presets ``five`` ... ``one`` (indices chosen along the arcs as in the paper).
    """
    from ..scene import Scene, Split

    cams = arc_cameras(n_train + n_test, width, height, model=model)
    depth = ellipsoid_depth(cams)
    mask = depth > 0
    col = point_color(cams.to(dtype=torch.float64).unproject(depth.double())).float() * mask[..., None]
    grey = col.mean(-1, keepdim=True).expand(-1, -1, -1, 3).contiguous()
    names = [f"v{i:03d}" for i in range(n_train + n_test)]
    test_idx = list(range(1, n_train + n_test, max(1, (n_train + n_test) // max(n_test, 1))))[:n_test]
    train_idx = [i for i in range(n_train + n_test) if i not in test_idx]

    def split(idx, train):
        c = cams[torch.tensor(idx)]
        c.image_ids = torch.arange(len(idx)) if train else torch.full((len(idx),), -1)
        return Split(names=[names[i] for i in idx], cameras=c, images=grey[idx], masks=mask[idx],
                     depths=depth[idx], colors=col[idx])

    train = split(train_idx, True)
    t = train.names
    pts = torch.randn(2000, 3)
    pts = pts / pts.norm(dim=-1, keepdim=True) * torch.tensor([1.0, 0.8, 0.9])
    sets = {"five": [t[0], t[len(t) // 3], t[-1 - len(t) // 3], t[-2], t[-1]]}
    sets["four"], sets["three"] = sets["five"][:4], sets["five"][:3]
    sets["two"], sets["one"] = [sets["five"][1], sets["five"][2]], [sets["five"][1]]
    return Scene(root="analytic", train=train, test=split(test_idx, False),
                 bounds=torch.tensor([[-1.0, -0.8, -0.9], [1.0, 0.8, 0.9]]), points=pts,
                 point_colors=torch.full((2000, 3), 0.5),
                 references={n: train.colors[i] for i, n in enumerate(t)}, reference_sets=sets)
