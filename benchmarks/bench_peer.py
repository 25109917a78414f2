"""The shared rasteriser benchmark scene (256x256, 16k-100k Gaussians): this tree against another commit.

The scene of the peer comparison (3DGS; 2DGS with ``--models 2DGS,3DGS``): a pinhole camera (fx = fy = 300,
principal point at the centre) at z = -3 looking down +z; ``torch.manual_seed(0)``; means
``(rand(N, 3) - 0.5) * 1.6``, isotropic scale 0.02, opacity 0.5, normalised ``randn(N, 4)`` quaternions, colours
from degree-3 SH coefficients ``randn(N, 16, 3) * 0.1`` evaluated towards the camera (+0.5, clamped at 0) inside
the timing (this tree, and a base commit that has it: the fused SH kernel the Gaussian backbones use; a base from
before it, such as 48f38bf: PyTorch ops, as its GaussianModel.colors); black background. One run = forward +
backward of ``sum(rgb)`` (gradients of means, quaternions, scales, opacities and SH).
Figures: median of the last 3 of 4 runs (``--runs``), wall seconds.

    .venv/bin/python benchmarks/bench_peer.py                         # this tree vs main, 1 and 2 threads
    .venv/bin/python benchmarks/bench_peer.py --base HEAD~1 --threads 2
    .venv/bin/python benchmarks/bench_peer.py --base none             # this tree only
    .venv/bin/python benchmarks/bench_peer.py --composited            # share of 3DGS pairs before each tile's stop

Old and new run alternately (run k of the base, run k of this tree, ...), so their ratio is measured under one
machine load; the base commit's kernels are built as a second extension (benchmarks/baseline.py).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from arcsem.backbones.gaussians.fused import sh_colors
from arcsem.backbones.gs2d.render import render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs
from arcsem.backbones.sh import eval_sh

from arcsem.cameras import Cameras

SIZES = (16_384, 50_000, 100_000)


def peer_scene(N: int) -> tuple[list[torch.Tensor], Cameras]:
    """``[means, quats, scales (N, 3), opacities, sh (N, 16, 3)]`` and the camera of the shared scene (float32)."""
    torch.manual_seed(0)
    means = (torch.rand(N, 3) - 0.5) * 1.6
    scales = torch.full((N, 3), 0.02)
    opac = torch.full((N,), 0.5)
    quats = torch.nn.functional.normalize(torch.randn(N, 4), dim=-1)
    sh = torch.randn(N, 16, 3) * 0.1
    w2c = torch.eye(4)
    w2c[2, 3] = 3.0
    K = torch.tensor([[300.0, 0.0, 128.0], [0.0, 300.0, 128.0], [0.0, 0.0, 1.0]])
    return [means, quats, scales, opac, sh], Cameras(w2c, K, 256, 256, "pinhole")


def torch_colors(means, sh_dc, sh_rest, cams):
    """SH colours as main's GaussianModel.colors (PyTorch ops)."""
    sh = torch.cat([sh_dc, sh_rest], 1)
    return torch.clamp_min(eval_sh(3, sh[None], means[None] - cams.centers[:, None]) + 0.5, 0.0)


def fused_colors(means, sh_dc, sh_rest, cams):
    """SH colours as this tree's GaussianModel.colors with the fused kernels."""
    return sh_colors(means, sh_dc, sh_rest, cams.centers, False, 3)


@torch.no_grad()
def composited_share(N: int, near: float = 0.01) -> tuple[int, float]:
    """3DGS on the shared scene: the number of (tile, splat) pairs and the share of them up to each tile's last
    composited pair (the rest lie behind pixels that stopped: the kernels neither gather nor sum them)."""
    from arcsem.backbones.gaussians import fused
    from arcsem.backbones.gaussians.raster_camera import pixel_projection

    (means, quats, scales, opac, sh), cams = peer_scene(N)
    P = pixel_projection(cams).to(means.dtype)
    m2, depth, conics, cov = fused.project_3dgs(means, quats, scales, means.new_zeros(1, N, 2), P, near)
    lists = fused.footprint_bin_3dgs(m2, depth, cov, opac, 1, near, cams.width, cams.height, 16)
    colors = fused_colors(means, sh[:, :1], sh[:, 1:], cams).reshape(N, 3)
    splats = fused._args("Splats3D", means2d=m2, conics=conics, opacities=opac, colors=colors, depth=depth,
                         background=colors.new_empty(0))
    res = fused.load_extension().composite3d_forward(splats, lists, fused._raster(1, cams.height, cams.width, 16))
    T = 16
    last = res.last.view(cams.height // T, T, cams.width // T, T).permute(0, 2, 1, 3).reshape(-1, T * T).long()
    jmax, off = last.max(1).values, lists.offsets
    used = torch.where(jmax >= 0, jmax - off[:-1] + 1, torch.zeros_like(jmax)).sum().item()
    return int(off[-1]), used / max(int(off[-1]), 1)


def run_once(fns: dict, dims: int, params: list[torch.Tensor], cams: Cameras) -> float:
    """Wall seconds of SH colours + render + backward of ``sum(rgb)``."""
    means, quats, scales, opac, sh_dc, sh_rest = [p.detach().clone().requires_grad_(True)
                                                  for p in (*params[:4], params[4][:, :1], params[4][:, 1:])]
    t0 = time.perf_counter()
    colors = fns["colors"](means, sh_dc, sh_rest, cams)
    out = fns["render"](means, quats, scales[:, :dims], opac, colors, cams, impl="cpp")
    out["rgb"].sum().backward()
    return time.perf_counter() - t0


def time_pair(renders: dict, model: str, N: int, runs: int) -> dict[str, float]:
    """Median of the last ``runs - 1`` runs per version, versions alternating (the first run warms up)."""
    params, cams = peer_scene(N)
    dims = 2 if model == "2DGS" else 3
    times: dict[str, list[float]] = {k: [] for k in renders}
    for r in range(runs):
        for name, fns in renders.items():
            t = run_once({"colors": fns["colors"], "render": fns[model]}, dims, params, cams)
            if r:
                times[name].append(t)
    return {k: statistics.median(v) for k, v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="git commit to compare with ('none': this tree only)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--models", default="3DGS")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--composited", action="store_true", help="print the share of 3DGS pairs composited, then stop")
    a = ap.parse_args()
    if a.composited:
        for N in (int(n) for n in a.sizes.split(",")):
            pairs, share = composited_share(N)
            print(f"3DGS, {N:,} splats: {pairs:,} (tile, splat) pairs, {100 * share:.1f} % up to each tile's last "
                  "composited one")
        return
    renders = {"this tree": {"2DGS": render_2dgs, "3DGS": render_3dgs, "colors": fused_colors}}
    if a.base != "none":
        from baseline import baseline_renderers

        base = baseline_renderers(a.base)
        colors = torch_colors if "sh_colors" not in base else (
            lambda means, dc, rest, cams, f=base["sh_colors"]: f(means, dc, rest, cams.centers, False, 3))
        renders = {a.base: {**base, "colors": colors}, **renders}
    print(f"shared scene 256x256, fwd+bwd of sum(rgb), median of the last {a.runs - 1} of {a.runs} runs, "
          f"alternating; load average {os.getloadavg()[0]:.2f}")
    names = list(renders)
    head = " | ".join(names)
    ratio = f" | {names[0]} / this tree" if len(names) > 1 else ""
    print(f"| model | threads | N | {head}{ratio} |")
    print("|---|---|---|" + "---|" * (len(names) + (len(names) > 1)))
    for nt in (int(t) for t in a.threads.split(",")):
        torch.set_num_threads(nt)
        for model in a.models.split(","):
            for N in (int(n) for n in a.sizes.split(",")):
                t = time_pair(renders, model, N, a.runs)
                cells = " | ".join(f"{t[k] * 1e3:.1f} ms" for k in names)
                r = f" | {t[names[0]] / t['this tree']:.2f}x" if len(names) > 1 else ""
                print(f"| {model} | {nt} | {N:,} | {cells}{r} |", flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
