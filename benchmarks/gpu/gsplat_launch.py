"""Why ``rasterization_2dgs``'s backward fails with "too many resources requested for launch" on 32-px tiles.

A tile of ``tile x tile`` pixels is one CUDA block of ``tile^2`` threads; a block may hold at most 65,536 registers
on Hopper (and every NVIDIA GPU since Kepler), so a kernel using ``R`` registers per thread launches only with
``tile^2 * R <= 65536``: at 32-px tiles (1024 threads) that is 64 registers. This runs gsplat's 2DGS and 3DGS
forward and backward at tiles of 8, 16 and 32 px with 3 and 5 channels (the bridge composites 5: colour and two
depth moments) and prints which launch, next to each rasterisation kernel's register count (``cuobjdump
-res-usage`` of the library gsplat loaded).

    python benchmarks/gpu/gsplat_launch.py
"""
from __future__ import annotations

import re
import subprocess

import torch


def attempt(two_d: bool, tile: int, channels: int) -> str:
    from gsplat import rasterization, rasterization_2dgs

    g = torch.Generator(device="cuda").manual_seed(0)
    n, W, H = 2000, 96, 64
    means = (torch.rand(n, 3, generator=g, device="cuda") - 0.5) * 2
    means[:, 2] += 4
    quats = torch.randn(n, 4, generator=g, device="cuda")
    scales = torch.rand(n, 3, generator=g, device="cuda") * 0.05 + 0.01
    opac = torch.rand(n, generator=g, device="cuda") * 0.5
    cols = torch.rand(1, n, channels, generator=g, device="cuda")
    ps = [t.requires_grad_() for t in (means, quats, scales, opac, cols)]
    K = torch.tensor([[[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]]], device="cuda")
    vm = torch.eye(4, device="cuda")[None]
    try:
        fn = rasterization_2dgs if two_d else rasterization
        out = fn(*ps, vm, K, W, H, tile_size=tile, sh_degree=None, packed=False)
        out[0].sum().backward()
        torch.cuda.synchronize()
        return "ok"
    except RuntimeError as e:
        return "FAILS: " + str(e).splitlines()[0][:80]


def registers() -> list[str]:
    import gsplat.cuda._backend as backend

    lib = backend._C.__file__
    try:
        text = subprocess.run(["cuobjdump", "-res-usage", lib], check=False, capture_output=True, text=True,
                              timeout=120).stdout
    except (OSError, subprocess.TimeoutExpired) as e:
        return [f"cuobjdump failed: {e}"]
    rows, fn = [], None
    for line in text.splitlines():
        m = re.search(r"Function (\S+):", line)
        if m:
            fn = m.group(1)
        r = re.search(r"REG:(\d+)", line)
        if r and fn and re.search(r"rasterize_to_pixels_(2|3)dgs_(bwd|fwd)_kernelILj(3|4|5|8)E", fn):
            rows.append((fn, int(r.group(1))))
            fn = None
    return [f"REG {reg:3d} (max threads per block {65536 // reg:4d})  {name[:90]}" for name, reg in sorted(rows)]


def main() -> None:
    for two_d in (True, False):
        for tile in (8, 16, 32):
            for ch in (3, 5):
                print(f"{'2DGS' if two_d else '3DGS'} tile {tile:2d} ({tile * tile:4d} threads) channels {ch}: "
                      f"{attempt(two_d, tile, ch)}")
    print("\n".join(registers()))


if __name__ == "__main__":
    main()
