"""Pseudo-colour benchmark: the paper's full scale, and k-d tree vs brute force on a reduced input.

Depth maps come from an analytic ellipsoid seen by look-at cameras (closed-form ray intersection,
``arcsem.colorize.analytic``; no rendering), colours from a smooth function of the 3-D point, so
accuracy is measured too. Usage::

    .venv/bin/python benchmarks/bench_pseudocolor.py --part full      # 32 x 3072x2048, 5 references
    .venv/bin/python benchmarks/bench_pseudocolor.py --part reduced   # 8 x 384x256: k-d tree vs torch.cdist
"""
from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time

import torch

from arcsem.colorize.analytic import arc_cameras, ellipsoid_depth, point_color
from arcsem.colorize.pseudocolor import cached_pseudo_colors, masked_points, pseudo_colors, pseudo_key

REFS5 = [0, 10, 19, 24, 31]  # leftmost, centre, rightmost (horizontal arc), angled, top (vertical arc)


def scene(n, w, h, focal_fov=3.5, dist=50.0):
    """Far pinhole cameras (paper: focal ~50,000 px at 3072 px wide) on two arcs, analytic depth."""
    cams = arc_cameras(n, w, h, "pinhole", dist=dist, fov_deg=focal_fov)
    depth = torch.cat([ellipsoid_depth(cams[i], chunk_rows=128) for i in range(n)])
    return cams, depth, depth > 0


def ref_colours(cams, depth, refs):
    return torch.stack([point_color(cams[r].to(dtype=torch.float64).unproject(depth[r:r + 1].double())[0]).float()
                        for r in refs])


def brute_force(cams, depth, mask, refs, ref_images, chunk=2048):
    """Reference: exact nearest neighbour by chunked torch.cdist over all reference points."""
    pts, cols = [], []
    for k, r in enumerate(refs):
        flat, p = masked_points(cams[r], depth[r], mask[r])
        pts.append(p.float())
        cols.append(ref_images[k].reshape(-1, 3)[flat])
    pts, cols = torch.cat(pts), torch.cat(cols)
    N, H, W = depth.shape
    colors, valid = torch.zeros(N, H, W, 3), torch.zeros(N, H, W, dtype=torch.bool)
    for v in range(N):
        if v in refs:
            continue
        flat, q = masked_points(cams[v], depth[v], mask[v])
        r = 2.0 * depth[v].reshape(-1)[flat] / cams.K[v, 0, 0]
        for s in range(0, len(flat), chunk):
            d, i = torch.cdist(q[s:s + chunk].float(), pts).min(1)
            ok = d <= r[s:s + chunk]
            colors[v].view(-1, 3)[flat[s:s + chunk][ok]] = cols[i[ok]]
            valid[v].view(-1)[flat[s:s + chunk][ok]] = True
    return colors, valid


def part_reduced(repeats=3):
    refs = [0, 3, 5, 6, 7]
    cams, depth, mask = scene(8, 384, 256)
    refi = ref_colours(cams, depth, refs)
    kd = []
    for _ in range(repeats):
        t = time.perf_counter()
        c1, v1 = pseudo_colors(cams, depth, mask, refs, refi, progress=False)
        kd.append(time.perf_counter() - t)
    t = time.perf_counter()
    c2, v2 = brute_force(cams, depth, mask, refs, refi)
    bf = time.perf_counter() - t
    others = [v for v in range(8) if v not in refs]
    agree = (v1[others] == v2[others]).float().mean().item()
    both = v1[others] & v2[others]
    cdiff = (c1[others] - c2[others]).abs().amax(-1)[both]
    print(f"reduced 8 views 384x256, 5 refs, {int(mask[others].sum())} query px:")
    print(f"  k-d tree median {statistics.median(kd):.3f} s (runs {', '.join(f'{x:.3f}' for x in kd)})")
    print(f"  brute force torch.cdist (1 run) {bf:.1f} s   ratio {bf / statistics.median(kd):.0f}x")
    print(f"  valid masks agree on {100 * agree:.3f}% of pixels; max colour difference where both valid "
          f"{cdiff.max().item():.4f} (ties/float32 rounding)")


def part_full(n=32, w=3072, h=2048):
    t0 = time.perf_counter()
    cams, depth, mask = scene(n, w, h)
    refi = ref_colours(cams, depth, REFS5)
    t_depth = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        key = pseudo_key(depth, refi, [str(r) for r in REFS5], None, 2.0, mask, cams)
        t_key = time.perf_counter() - t1
        t2 = time.perf_counter()
        colors, valid, _ = cached_pseudo_colors(
            tmp, key, lambda: pseudo_colors(cams, depth, mask, REFS5, refi, progress=True))
        t_pc = time.perf_counter() - t2
        t3 = time.perf_counter()
        _, valid2, hit2 = cached_pseudo_colors(tmp, key, lambda: (_ for _ in ()).throw(RuntimeError))
        t_hit = time.perf_counter() - t3
    others = [v for v in range(n) if v not in REFS5]
    cover = (valid[others].sum() / mask[others].sum()).item()
    err = []
    for v in others[::6]:
        gt = point_color(cams[v].to(dtype=torch.float64).unproject(depth[v:v + 1].double())[0]).float()
        err.append((colors[v] - gt).abs()[valid[v]].mean().item())
    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(f"full {n} views {w}x{h}, 5 refs, {int(mask[REFS5].sum()):,} reference points, "
          f"{int(mask[others].sum()):,} query px")
    print(f"  analytic depth + reference colours: {t_depth:.1f} s (not part of the pseudo-colour time)")
    print(f"  cache key (hash of depth maps, masks, refs): {t_key:.1f} s")
    print(f"  pseudo-colours incl. cache write: {t_pc:.1f} s; cache hit reload: {t_hit:.1f} s (hit={hit2})")
    print(f"  coverage of masked query px: {100 * cover:.2f}%; mean |error| vs analytic colour: "
          f"{statistics.mean(err):.4f}")
    print(f"  peak RSS (ru_maxrss, whole process): {rss_gb:.2f} GB")
    assert torch.equal(valid, valid2)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", choices=["full", "reduced", "both"], default="both")
    a = ap.parse_args()
    if a.part in ("reduced", "both"):
        part_reduced()
    if a.part in ("full", "both"):
        part_full()
