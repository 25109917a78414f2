"""Where a stage-1 model's held-out error lies: image error by region, depth error by surface tilt.

For a finished stage-1 run (``run_dir/checkpoints/last.pt``) on a dataset with ground-truth masks,
depth and normals (the built-in scene), over the held-out views:

* image MSE / PSNR against the noise-free images in three regions: the specimen's interior (mask
  eroded by 2 px), a 2-px band around its silhouette, and everything else (substrate, background),
  with each region's share of the squared error;
* the median depth error (the rendered ``median_depth`` or ``depth``, inside the eroded mask) in
  scene units and in % of ``scene.scale``, its signed median (positive = behind the surface), and
  the same restricted to pixels facing the camera (``cos(tilt) > c``, tilt between the ground-truth
  normal and the viewing direction);
* with ``--surfels`` (a Gaussian model of the built-in synthetic scene, whose exact surface is known):
  where the splats that draw the specimen sit. Each splat is weighted by its total blending weight
  over the specimen's pixels in these views; reported are weighted quantiles of the signed distance
  of its centre to the true surface (negative: inside) and, for 2DGS, of the angle between its normal
  and the surface normal there.

Usage::

    .venv/bin/python benchmarks/error_breakdown.py RUN_DIR [--split test|train] [--surfels]
"""
from __future__ import annotations

import argparse
import math

import torch
import torch.nn.functional as F
from omegaconf import OmegaConf

from arcsem.data import load_scene
from arcsem.errors import ArcsemError
from arcsem.runs import load_stage1
from arcsem.train.checkpoint import load_checkpoint
from arcsem.train.evaluate import render_view
from arcsem.train.stage1 import prepare_scene, train_config


def bands(mask: torch.Tensor, px: int = 2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(interior, edge, outside)`` bool ``[H, W]`` masks: ``mask`` eroded / dilated by ``px``."""
    m = mask.float()[None, None]
    k = 2 * px + 1
    dil = F.max_pool2d(m, k, 1, px)[0, 0] > 0
    ero = -F.max_pool2d(-m, k, 1, px)[0, 0] > 0
    return ero, dil & ~ero, ~dil


def psnr_of(mse: float) -> float:
    return -10.0 * math.log10(mse) if mse > 0 else math.inf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run_dir")
    ap.add_argument("--split", default="test", choices=("test", "train"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--surfels", action="store_true", help="where the splats sit (built-in synthetic scene only)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    ckpt = f"{args.run_dir}/checkpoints/last.pt"
    cfg = OmegaConf.create(load_checkpoint(ckpt)["config"])
    scene = load_scene(cfg.dataset)
    backbone, _ = load_stage1(ckpt, scene)
    scene = prepare_scene(scene, train_config(cfg))
    split = scene.test if args.split == "test" else scene.train
    for what in ("clean", "masks", "depths", "normals"):
        if getattr(split, what) is None:
            raise ArcsemError(f"{args.run_dir}: the dataset has no ground-truth {what} for the {args.split} views")
    sse = {"interior": 0.0, "edge": 0.0, "outside": 0.0}
    count = dict.fromkeys(sse, 0)
    errs, cos = [], []
    for i in range(len(split)):
        out = render_view(backbone, split, i)  # against the clean image: the mean ACT
        err2 = ((out["rgb"].clamp(0, 1) - split.clean[i]) ** 2).mean(-1)
        mask = split.masks[i].reshape(err2.shape).bool()
        regions = dict(zip(sse, bands(mask)))
        for name, r in regions.items():
            sse[name] += float(err2[r].sum())
            count[name] += int(r.sum())
        depth = out.get("median_depth", out["depth"])[..., 0]
        gt = split.depths[i]
        valid = regions["interior"] & (gt > 0)
        errs.append((depth - gt)[valid].double())
        n = split.normals[i].double()
        cos.append((-(n * split.cameras[i : i + 1].forward[0].double()).sum(-1))[valid])
    total_sse, total_n = sum(sse.values()), sum(count.values())
    print(f"{args.split} views: {len(split)}; image PSNR {psnr_of(total_sse / total_n):.2f} dB")
    for name, err in sse.items():
        mse = err / max(count[name], 1)
        print(f"  {name:9s} {100 * count[name] / total_n:5.1f} % of pixels, PSNR {psnr_of(mse):6.2f} dB, "
              f"{100 * err / total_sse:5.1f} % of the squared error")
    e, c = torch.cat(errs), torch.cat(cos)
    scale = float(scene.scale[0])
    med = float(e.abs().median())
    print(f"depth (interior, {e.numel()} px): median |error| {med:.4f} = {100 * med / scale:.2f} % of "
          f"{scene.scale[1]}; signed median {float(e.median()):+.4f} (positive: behind the surface)")
    for lo in (0.3, 0.5, 0.7):
        k = c > lo
        m = float(e[k].abs().median()) if k.any() else math.nan
        print(f"  cos(tilt) > {lo}: {100 * float(k.double().mean()):4.1f} % of those pixels, "
              f"median |error| {m:.4f} = {100 * m / scale:.2f} %")
    if args.surfels:
        surfels(backbone, split, cfg, scale, scene.scale[1])


def weighted_quantiles(x: torch.Tensor, w: torch.Tensor, qs=(0.1, 0.25, 0.5, 0.75, 0.9)) -> list[float]:
    """Quantiles of ``x [N]`` under non-negative weights ``w [N]``."""
    order = torch.argsort(x)
    cw = torch.cumsum(w[order], 0)
    at = torch.searchsorted(cw, torch.tensor(qs, dtype=cw.dtype) * cw[-1]).clamp(max=len(x) - 1)
    return [float(v) for v in x[order][at]]


def surfels(backbone, split, cfg, scale: float, scale_name: str) -> None:
    """Weighted distance of the splat centres to the true surface, and surfel normal error (2DGS)."""
    from arcsem.synthetic.sdf import make_grain
    from arcsem.synthetic.trace import sdf_gradient

    if cfg.dataset.kind != "synthetic" or not hasattr(backbone, "model"):
        raise ArcsemError("--surfels needs a Gaussian model of the built-in synthetic scene")
    grain = make_grain(int(cfg.dataset.seed), int(cfg.dataset.get("n_spines", 30))).to(torch.float64)
    m = backbone.model
    weight = torch.zeros(len(m.means), dtype=torch.float64)
    params = [p.detach() for p in (m.means, m.quats, m.scales, m.opacities)]
    for i in range(len(split)):
        cams = split.cameras[i : i + 1]
        ones = torch.ones(len(m.means), 3, dtype=params[0].dtype, requires_grad=True)
        out = backbone._rasterize(*params, ones, cams, tile=backbone.cfg.tile, impl=backbone.cfg.rasterizer)
        mask = split.masks[i].reshape(out["rgb"].shape[1:3]).to(out["rgb"].dtype)
        (grad,) = torch.autograd.grad((out["rgb"][0, ..., 0] * mask).sum(), ones)
        weight += grad[:, 0].double()  # d(sum of rendered values)/d(colour) = the splat's blending weight
    with torch.no_grad():
        centre = m.means.detach().double()
        dist = grain.sdf(centre)
    q = weighted_quantiles(dist, weight)
    print("splat centres, distance to the surface (weighted by blending weight on the specimen; 10/25/50/75/90 %): "
          + " ".join(f"{100 * v / scale:+.2f}" for v in q) + f" % of {scale_name}")
    if m.scales.shape[1] == 2:
        from arcsem.rotations import quat_to_rotmat

        with torch.no_grad():
            n = quat_to_rotmat(m.quats.detach().double())[:, :, 2]
            true_n, _ = sdf_gradient(grain.sdf, centre)
            angle = torch.rad2deg(torch.acos((n * true_n).sum(-1).abs().clamp(max=1.0)))
        q = weighted_quantiles(angle, weight, (0.25, 0.5, 0.75, 0.9))
        print("surfel normal vs surface normal (weighted; 25/50/75/90 %): " + " ".join(f"{v:.1f}" for v in q) + " deg")


if __name__ == "__main__":
    main()
