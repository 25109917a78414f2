"""The fused kernels of this tree against another commit's, bit for bit: for refactorings of the C++ code.

Builds the other commit's kernels beside this tree's (the Gaussian rasteriser through ``baseline.py``, the
Plenoxels marcher from its ``cpp/`` sources) and compares every output and every gradient with ``torch.equal``:

* Gaussians: 2DGS and 3DGS, pinhole and orthographic, float32 and float64, a small scene (60 splats, 48x40, an
  opaque stack that stops pixels early) and a larger one (3,000 splats, 130x97: many pairs per tile), with a
  learned background; 2DGS also with frozen geometry (the colour-only backward).
* Plenoxels: live masks, forward, backward (sparse rows, density, SH, per-ray ACT) and the pruning weights, SH
  degrees 0, 2 and 3, with and without ACT, float32 and float64.

    .venv/bin/python benchmarks/bit_identity.py [--base main] [--part gaussians|plenoxels]

Prints one line per part; exits 1 at the first difference, naming the case. (Timing is another question:
``bench_peer.py``, ``bench_plenoxels_marcher.py``.)
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))


def gaussian_scene(kind: str, model: str, n: int, W: int, H: int, dtype: torch.dtype):
    """Splats of ``kind`` (``2DGS``/``3DGS``) in front of two cameras; made in float64 and cast."""
    from arcsem.cameras import Cameras, look_at

    g, d = torch.Generator().manual_seed(0), torch.float64
    means = (torch.rand(n, 3, generator=g, dtype=d) - 0.5) * torch.tensor([1.2, 1.0, 1.0], dtype=d)
    quats = torch.randn(n, 4, generator=g, dtype=d)
    scales = torch.rand(n, 2 if kind == "2DGS" else 3, generator=g, dtype=d) * 0.08 + 0.005
    scales[:5] *= 4  # straddle tiles
    opac = torch.rand(n, generator=g, dtype=d) * 0.9 + 0.05
    opac[5:40] = 0.999  # an opaque stack: pixels behind it stop early
    means[5:40, :2] = means[5, :2]
    means[5:40, 2] = torch.linspace(-0.4, 0.4, 35, dtype=d)
    colors = torch.rand(2, n, 3, generator=g, dtype=d)
    eye = torch.tensor([[0.0, 0.0, -4.0], [0.6, -0.3, -3.9]], dtype=d)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=d))
    f = W * 1.0 if model == "pinhole" else W / 4.0
    K = torch.tensor([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]], dtype=d).repeat(2, 1, 1)
    params = [p.to(dtype) for p in (means, quats, scales, opac, colors)]
    return params, Cameras(w2c, K, W, H, model).to(dtype=dtype)


def gaussian_run(render, params, cams, geometry: bool) -> dict:
    """Outputs and gradients of a random linear loss of every output (geometry False: colours only)."""
    ps = [p.clone().requires_grad_(geometry or i == 4) for i, p in enumerate(params)]
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=ps[0].dtype, requires_grad=True)
    out = render(*ps, cams, background=bg, impl="cpp")
    g = torch.Generator().manual_seed(1)
    used = {k: v for k, v in sorted(out.items()) if torch.is_tensor(v) and v.requires_grad}
    sum((v * torch.randn(v.shape, generator=g, dtype=v.dtype)).sum() for v in used.values()).backward()
    res = {k: v.detach() for k, v in out.items() if torch.is_tensor(v)}
    res.update({f"grad{i}": p.grad for i, p in enumerate(ps) if p.grad is not None}, grad_bg=bg.grad)
    return res


def check_gaussians(base: str) -> int:
    from arcsem.backbones.gs2d.render import render_2dgs
    from arcsem.backbones.gs3d.render import render_3dgs
    from baseline import baseline_renderers

    old, new, cases = baseline_renderers(base), {"2DGS": render_2dgs, "3DGS": render_3dgs}, 0
    for kind in ("2DGS", "3DGS"):
        for model in ("pinhole", "orthographic"):
            for dtype in (torch.float32, torch.float64):
                for n, W, H in ((60, 48, 40), (3000, 130, 97)):
                    for geometry in (True, False) if kind == "2DGS" else (True,):
                        params, cams = gaussian_scene(kind, model, n, W, H, dtype)
                        a, b = (gaussian_run(r[kind], params, cams, geometry) for r in (new, old))
                        differ = [k for k in a if k not in b or not torch.equal(a[k], b[k])]
                        if differ or a.keys() != b.keys():
                            raise SystemExit(f"gaussians differ: {kind} {model} {dtype} N={n} geometry={geometry}: "
                                             f"{differ or sorted(set(a) ^ set(b))}")
                        cases += 1
    return cases


def plenoxels_kernel(base: str):
    """The marcher of commit ``base``, built from its ``backbones/plenoxels/cpp/`` as a second extension."""
    from arcsem import cext

    folder = Path(tempfile.mkdtemp(prefix=f"plx_{base.replace('/', '_')}_"))
    names = subprocess.run(["git", "ls-tree", "--name-only", base, "backbones/plenoxels/cpp/"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for name in names:
        out = subprocess.run(["git", "show", f"{base}:{name}"], cwd=ROOT, capture_output=True, check=True).stdout
        (folder / Path(name).name).write_bytes(out)
    sources = tuple(folder / n for n in ("render.cpp", "module.cpp") if (folder / n).is_file())
    mod = cext.load(cext.Extension(prefix="arcsem_plenoxels_base", sources=sources, what=f"{base}'s marcher"))
    if mod is None:
        raise SystemExit(f"error: the marcher of {base} did not build")
    return mod


def plenoxels_calls(mod, o, d, idx, coords, dens, sh, aw, ab, bounds, degree: int, act: bool):
    """live, forward, backward (with output gradients g) and max_weights of ``mod``, whichever boundary it has
    (argument structs, or the positional one before them)."""
    from arcsem.backbones.plenoxels import fused

    step, scale, stop, shift = 0.02, 1.3, 1e-3, fused.SKIP_SHIFT
    live = mod.live(idx, coords, dens, shift)
    if not hasattr(mod, "VoxelGrid"):  # the positional boundary
        pos = (o, d, idx, live[0], live[1], shift, dens, sh, aw, ab, bounds, step, scale, stop, degree, act)
        fwd = mod.forward(*pos)
        back = lambda g: mod.backward(*pos, *fwd, *g, fused.slots(dens.numel()))
        mw = mod.max_weights(o, d, idx, live[0], live[1], shift, dens, bounds, step, scale, stop)
        return live, fwd, back, mw

    def struct(kind, **fields):
        s = getattr(mod, kind)()
        for k, v in fields.items():
            setattr(s, k, v)
        return s

    rays = struct("Rays", origins=o, directions=d, step=step, scale=scale, stop=stop)
    grid = struct("VoxelGrid", index=idx, cell_live=live[0], block_dist=live[1], bounds=bounds, shift=shift)
    field = struct("Field", density=dens, sh=sh, degree=degree, act=act, act_w=aw, act_b=ab)
    out = mod.forward(rays, grid, field)
    fwd = (out.rgb, out.alpha, out.wt, out.mom)

    def back(g):
        r = mod.backward(rays, grid, field, out, struct("Marched", rgb=g[0], alpha=g[1], wt=g[2], mom=g[3]),
                         fused.slots(dens.numel()))
        return r.rows, r.density, r.sh, r.act_w, r.act_b

    mw = mod.max_weights(rays, grid, struct("Field", density=dens, sh=dens.new_zeros(0), degree=0, act=False))
    return live, fwd, back, mw


def check_plenoxels(base: str) -> int:
    from arcsem.backbones.plenoxels import fused
    from arcsem.backbones.plenoxels.grid import build_index, occupied_coords

    old, new, cases = plenoxels_kernel(base), fused.load_extension(), 0
    for dtype in (torch.float32, torch.float64):
        for degree, K in ((0, 1), (2, 9), (3, 16)):
            for act in (False, True):
                gen = torch.Generator().manual_seed(7 * degree + act)
                rnd = lambda *shape, gen=gen: torch.randn(*shape, generator=gen, dtype=torch.float64)
                occ = torch.rand(18, 15, 21, generator=gen) > 0.4
                idx = build_index(occ)
                m, R = int(occ.sum()), 700
                dens = (torch.rand(m, generator=gen, dtype=torch.float64) * 30 - 5).to(dtype)
                sh = (0.3 * rnd(m, K, 3)).to(dtype)
                o = (0.3 * rnd(R, 3) + torch.tensor([-3.0, 0, 0], dtype=torch.float64)).to(dtype)
                d = (0.3 * rnd(R, 3) + torch.tensor([1.0, 0, 0], dtype=torch.float64)).to(dtype)
                aw, ab = ((1 + 0.3 * rnd(R, 3)).to(dtype), (0.1 * rnd(R, 3)).to(dtype)) if act else (
                    torch.zeros(0, dtype=dtype), torch.zeros(0, dtype=dtype))
                bounds = torch.tensor([[-1.0, -0.8, -1.1], [1.0, 0.9, 1.2]])
                args = (o, d, idx, occupied_coords(idx), dens, sh, aw, ab, bounds, degree, act)
                (la, fa, ba, ma), (lb, fb, bb, mb) = plenoxels_calls(new, *args), plenoxels_calls(old, *args)
                g = [rnd(*t.shape).to(dtype) for t in fa]
                parts = {"live": (la, lb), "forward": (fa, fb), "backward": (ba(g), bb(g)), "max_weights": ([ma], [mb])}
                for part, (x, y) in parts.items():
                    if not all(torch.equal(p, q) for p, q in zip(x, y, strict=True)):
                        raise SystemExit(f"plenoxels differ: {part}, {dtype}, degree {degree}, ACT {act}")
                cases += 1
    return cases


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="the commit to compare with (default: main)")
    ap.add_argument("--part", choices=["gaussians", "plenoxels"], action="append", help="only this part")
    args = ap.parse_args()
    for part in args.part or ["gaussians", "plenoxels"]:
        n = (check_gaussians if part == "gaussians" else check_plenoxels)(args.base)
        print(f"{part}: bit-identical to {args.base} in {n} cases (every output and gradient)")


if __name__ == "__main__":
    main()
