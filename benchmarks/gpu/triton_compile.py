"""Compile the Triton kernels (the 2DGS rasteriser's, tile binning's, SH colours' and densification statistics',
``rasterizer=triton``, and the D-SSIM and normal-consistency losses') for a GPU architecture, on a machine without a
GPU.

Triton compiles ahead of time for a named target (its own LLVM and ptxas, no driver): this checks that the kernels
are ones Triton compiles (its interpreter, which the CPU tests run, accepts more) and reports what the GPU would get:
registers a thread, spilled bytes, shared memory::

    python benchmarks/gpu/triton_compile.py                 # sm_90 (H100/H200), float32, 16-px tiles, 8 warps
    python benchmarks/gpu/triton_compile.py --arch 80 --tile 8
    TRITON_CACHE_DIR=$(mktemp -d) python benchmarks/gpu/triton_compile.py   # the compile times of a bare machine

Prints one line per kernel; exit status 1 when a kernel does not compile.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def signatures(tile: int) -> dict[str, tuple[dict, dict]]:
    """Each kernel's argument types and constants as ``rasterizer=triton`` launches them (float32 tensors)."""
    f, i32, i64 = "*fp32", "*i32", "*i64"
    common = {"tab": f, "box": i32, "off": i64, "ids": i64, "prm": f, "bg": f}
    sizes = {"H": "i32", "W": "i32", "TX": "i32", "TY": "i32", "near": "fp32"}
    fwd = {**common, **{k: f for k in ("rgb", "nrm", "tf_", "alpha_", "wz_", "depth_", "med_", "dist_", "m1_", "m2_",
                                       "mref_")}, "last_": i32, "medi_": i32, **sizes}
    bwd = {**common, **{k: f for k in ("tf_", "alpha_", "wz_", "m1_", "m2_", "mref_")}, "last_": i32, "medi_": i32,
           **{k: f for k in ("g_rgb", "g_nrm", "g_alpha", "g_depth", "g_med", "g_dist", "grad")}, **sizes}
    from arcsem.backbones.gaussians.raster import MAX_ALPHA, MIN_ALPHA, MIN_T
    from arcsem.backbones.gaussians.triton2d import TABLE, _block, _reduction

    shared = {"TILE": tile, "BLOCK": _block(tile), "NCOL": TABLE, "MAX_ALPHA_": MAX_ALPHA, "MIN_ALPHA_": MIN_ALPHA}
    fwd_c = {**shared, "HAS_BG": True, "MIN_T_": MIN_T}
    bwd_c = {**shared, "HAS_BG": True, "G_RGB": True, "G_NRM": True, "G_ALPHA": True, "G_DEPTH": True, "G_MED": True,
             "G_DIST": True, "GEO": True}
    bwd_c["REDUCE"], bwd_c["NW"] = _reduction(tile)
    foot = {"Hm": f, "op": f, "prm": "*fp64", **{k: i64 for k in ("radius_", "rects_", "eff_")}, "depth_": "*fp64",
            **{k: "i32" for k in ("M", "N", "W", "H", "TX", "TY")}}
    pf = {**{k: f for k in ("means", "quats", "scales", "opac", "colors", "P", "view", "table", "hm")}, "N": "i32",
          "C": "i32"}
    pb = {**{k: f for k in ("means", "quats", "scales", "P", "view", "gtab", "g_means", "g_quats", "g_scales", "g_opac",
                            "g_colors", "g_shift")}, "N": "i32", "C": "i32"}
    proj = {"ORTHO": False, "NCOL": TABLE, "BLOCK": 128}
    from arcsem.losses.triton_ssim import BLOCK as SSIM_BLOCK

    ssim = {"K": 11, "BLOCK": SSIM_BLOCK}  # the D-SSIM loss's kernels (losses/triton_ssim.py): 11-tap window, RGB
    ssim_sig = {
        "_row_pass_forward": ({"x": f, "y": f, "g": f, "h": f, "L": "i32", "n": "i32"}, {**ssim, "CH": 3}),
        "_column_pass_forward": ({"h": f, "g": f, "prm": f, "smap": f, "stats": f, "H": "i32", "L": "i32", "n": "i32"},
                                 ssim),
        "_row_pass_backward": ({"gmap": f, "stats": f, "g": f, "prm": f, "h": f, "L": "i32", "n": "i32"},
                               {**ssim, "CH": 3}),
        "_column_pass_backward": ({"h": f, "g": f, "x": f, "y": f, "gx": f, "H": "i32", "L": "i32", "n": "i32"}, ssim)}
    from arcsem.losses.triton_normals import BLOCK as NC_BLOCK

    px = {"n_pix": "i32", "H": "i32", "W": "i32"}  # the normal-consistency loss's (losses/triton_normals.py)
    nc_sig = {"normals._forward": ({**{k: f for k in ("D", "o", "d", "N", "A", "part")}, **px}, {"BLOCK": NC_BLOCK}),
              "normals._backward_normals": ({**{k: f for k in ("D", "o", "d", "N", "A", "scale", "gN", "gd")}, **px},
                                            {"BLOCK": NC_BLOCK}),
              "normals._backward_depth": ({"d": f, "gd": f, "gD": f, **px}, {"BLOCK": NC_BLOCK})}
    from arcsem.backbones.gaussians._triton_sh import BLOCK as SH_BLOCK

    shc = {"ORTHO": False, "ACT": True, "BLOCK": SH_BLOCK}  # the SH colours' (gaussians/_triton_sh.py)
    sh_in = {k: f for k in ("means", "dc", "rest", "origins", "aw", "ab")}
    sh_sig = {"sh._forward": ({**sh_in, "rgb": f, "N": "i32", "C": "i32", "R": "i32", "K": "i32"}, shc),
              "sh._backward": ({**sh_in, **{k: f for k in ("g", "g_means", "g_dc", "g_rest", "g_act")}, "N": "i32",
                                "C": "i32", "R": "i32", "K": "i32"}, shc)}
    from arcsem.backbones.gaussians._triton_densify import BLOCK as DENSIFY_BLOCK

    dens = {"densify._accumulate": ({**{k: f for k in ("g", "means", "Rt", "K")}, "visible": "*i1", "radii": i64,
                                     **{k: f for k in ("grad_sum", "count", "max_radii")}, "N": "i32", "C": "i32",
                                     "half_w": "fp32", "half_h": "fp32"}, {"ORTHO": False, "BLOCK": DENSIFY_BLOCK})}
    from arcsem.backbones.gaussians._triton2d_bin import BLOCK as BIN_BLOCK

    dens["bin._expand"] = ({**{k: i64 for k in ("rects", "rank", "ends", "key", "splat")},
                            **{k: "i32" for k in ("M", "N", "TX", "TY")}}, {"BLOCK": BIN_BLOCK})
    return {**ssim_sig, **nc_sig, **sh_sig, **dens, "project_forward": (pf, proj), "project_backward": (pb, {**proj, "DT": "float32"}),
            "footprint_kernel": (foot, {"TILE": tile, "BLOCK": 256}),
            "forward_kernel": (fwd, {**fwd_c, "DT": "float32"}), "backward_kernel": (bwd, {**bwd_c, "DT": "float32"})}


def ptxas_usage(ptx: str, arch: int) -> str:
    """Triton's bundled ``ptxas -v`` on the kernel's PTX: registers a thread and spill stores (no driver needed)."""
    import re
    import subprocess
    import tempfile

    import triton

    out = ""
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "k.ptx"
        src.write_text(ptx)
        for ptxas in sorted((Path(triton.__file__).parent / "backends" / "nvidia" / "bin").glob("ptxas*")):
            r = subprocess.run([str(ptxas), "-v", f"--gpu-name=sm_{arch}a" if arch >= 90 else f"--gpu-name=sm_{arch}",
                                str(src), "-o", str(Path(d) / "k.cubin")], capture_output=True, text=True, check=False)
            if r.returncode == 0:  # (Triton ships two; the PTX version decides which one reads it)
                out = r.stdout + r.stderr
                break
    regs = re.search(r"Used (\d+) registers", out)
    spill = re.search(r"(\d+) bytes spill stores", out)
    if regs is None:
        return "ptxas usage not read"
    return f"{regs.group(1)} registers a thread, {spill.group(1) if spill else '?'} bytes of spill stores"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", type=int, default=90, help="CUDA compute capability x 10 (90: H100/H200)")
    ap.add_argument("--tile", type=int, default=16)
    ap.add_argument("--warps", type=int, default=None, help="default: what rasterizer=triton launches")
    ap.add_argument("--sum", default=None, help="the backward's reduction (triton2d.BACKWARD_SUM; default: its own)")
    args = ap.parse_args(argv)
    if os.environ.get("TRITON_INTERPRET", "0") not in ("", "0"):
        print("error: TRITON_INTERPRET is set: the interpreter compiles nothing", file=sys.stderr)
        return 2
    import triton
    import triton.language as tl
    from arcsem.backbones.gaussians import (
        _triton2d_bin,
        _triton2d_footprint,
        _triton2d_kernels,
        _triton2d_project,
        _triton_densify,
        _triton_sh,
        triton2d,
    )
    from arcsem.backbones.gaussians.triton2d import _warps
    from arcsem.losses import triton_normals, triton_ssim
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    args.warps = args.warps or _warps(args.tile)
    triton2d.BACKWARD_SUM = args.sum or triton2d.BACKWARD_SUM

    failed = 0
    for name, (sig, consts) in signatures(args.tile).items():
        consts = {k: getattr(tl, v) if k == "DT" else v for k, v in consts.items()}
        sig = {**sig, **{k: "constexpr" for k in consts}}
        module = {"footprint_kernel": _triton2d_footprint, "project_forward": _triton2d_project,
                  "project_backward": _triton2d_project}.get(name, triton_ssim if "pass" in name else
                                                             triton_normals if name.startswith("normals.")
                                                             else _triton_sh if name.startswith("sh.")
                                                             else _triton_densify if name.startswith("densify.")
                                                             else _triton2d_bin if name.startswith("bin.")
                                                             else _triton2d_kernels)
        options = ({"num_warps": 4, "enable_fp_fusion": False} if name == "footprint_kernel"
                   else {"num_warps": 4} if name.startswith(("project", "normals.", "sh.", "densify.", "bin."))
                   else {"num_warps": 8} if "pass" in name else {"num_warps": args.warps})
        t0 = time.perf_counter()
        try:
            k = triton.compile(ASTSource(fn=getattr(module, name.split(".")[-1]), signature=sig, constexprs=consts),
                               target=GPUTarget("cuda", args.arch, 32), options=options)
        except Exception as e:  # noqa: BLE001 - report any compiler failure as one line
            failed += 1
            print(f"{name}: does not compile for sm_{args.arch}: {type(e).__name__}: {str(e).splitlines()[0]}")
            continue
        took = time.perf_counter() - t0  # what a bare GPU machine's first run pays (its CPU's speed)
        print(f"{name}: compiled for sm_{args.arch} in {took:.1f} s, {options['num_warps']} warps, {args.tile}-px tiles: "
              f"cubin {len(k.asm['cubin'])} bytes, shared {k.metadata.shared} bytes; {ptxas_usage(k.asm['ptx'], args.arch)}"
              f"; {k.asm['ptx'].count('bar.sync') + k.asm['ptx'].count('barrier.sync')} barriers in its PTX")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
