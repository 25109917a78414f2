"""Probes of the seventeenth session (2026-11-29): settings of the stage-2 target tried in closed form, not adopted.

Each builds stage 2's inputs for a run folder as ``benchmarks/match_outside.py`` does and scores, against the true
colour of the non-reference training views' specimen pixels outside the references' coverage (true depth):

* ``confidence``: the pseudo-colour target with the surface spread at each ``colorize.surface.confidence`` (the
  spread on, the run's other settings), against the spread off; and which spread the one-reference validation
  chooses at each confidence, with the target it then gives;
* ``texture``: the grey prior (``E[rgb | grey]``) against a prior of grey and the local standard deviation of the
  grey (Welsh, Ashikhmin and Mueller 2002's neighbourhood statistic; a 9x9 window, within the mask or not);
* ``filters``: the surface spread with the model depth's doubtful pixels left out of its graph (the 10 or 20 % with
  the largest gap between expected and median depth, depth distortion, or transparency; and those with under two
  other views agreeing or with free-space violations), and the share of the gross depth errors (> 10 footprints
  off the true depth) each catches;
* ``gap_target``: the whole target outside the coverage (the spread unshaded over the pseudo-colours and prior)
  with the spread's graph on every model-depth pixel or without those of the largest expected-median depth gap.

Not maintained (see README.md here)::

    .venv/bin/python benchmarks/archive/stage2_probes.py {confidence,texture,filters,gap_target} RUN_DIR [RUN_DIR ...] \
        [--references one three]
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # match_outside in benchmarks/ (no package)
import match_outside

CACHE = Path("/tmp/arcsem_stage2_probes")


def _db(pred, gt, sel) -> float:
    return -10 * math.log10(float(((pred - gt)[sel] ** 2).mean())) if bool(sel.any()) else float("nan")


def setup(run: Path, refs_spec: str, **colorize) -> dict:
    """The run's stage-2 inputs for ``refs_spec`` (``colorize``: overrides of its ``colorize`` group;
    ``match_outside.open_run``), with the coverage split, the true colour, the surface geometry and the grey."""
    from arcsem.colorize import inputs as prep
    from arcsem.colorize.coverage import coverage_masks

    r = match_outside.open_run(run, refs_spec, cache_dir=str(CACHE), **colorize)
    split, masks, ridx = r.split, r.masks.bool(), r.refs.indices.tolist()
    covered = coverage_masks(split.cameras[ridx], split.depths[ridx], masks[ridx], split.cameras, split.depths, masks)
    outside = masks & ~covered
    outside[ridx] = False
    return {**vars(r), "masks": masks, "ridx": ridx, "outside": outside, "gt": split.colors.float(),
            "geo": prep.SurfaceGeometry(r.backbone, split), "grey": split.images.float().mean(-1)}


def confidence(run: Path, refs_spec: str) -> str:
    from arcsem.colorize import inputs as prep

    line = f"{run.name} {refs_spec}:"
    s = setup(run, refs_spec)
    cc, out, gt = s["cc"], s["outside"], s["gt"]
    args = (s["cfg"], s["ckpt"], s["backbone"], s["split"], s["masks"], s["refs"], CACHE, s["geo"])
    off, _, _ = prep.pseudo_target(dataclasses.replace(cc, surface=dataclasses.replace(cc.surface, mode="off")), *args)
    line += f" spread off {_db(off, gt, out):.2f}"
    extractor, space, _ = prep.feature_extractor(cc, s["cfg"], s["ckpt"], s["backbone"], s["split"], s["masks"], CACHE,
                                                 s["rc"].features)
    guidance = prep.guidance_factory(cc, extractor, space, s["split"], s["geo"], CACHE)(s["ridx"], s["refs"].images)
    for c in (0.34, 0.45, 0.6, 0.7, 0.8, 0.9):
        at = dataclasses.replace(cc, surface=dataclasses.replace(cc.surface, confidence=c))
        tgt, _, info = prep.pseudo_target(dataclasses.replace(at, surface=dataclasses.replace(at.surface, mode="fill")),
                                          *args)
        filled = out & info["covered"].bool() & ~info["valid2d"].bool()
        chosen, val = prep.validate_settings(at, s["split"], s["masks"], s["refs"], s["geo"], guidance)
        tv, _, _ = prep.pseudo_target(chosen, *args)
        line += (f" | {c}: reach {float(filled.sum() / out.sum()):.2f}, target {_db(tgt, gt, out):.2f}; validation: "
                 f"{val['surface'] if val else '-'} -> {_db(tv, gt, out):.2f}")
    return line


def _local_std(grey: torch.Tensor, masks: torch.Tensor | None, r: int = 4) -> torch.Tensor:
    """``[N, H, W]`` the grey's standard deviation over ``(2r+1)^2`` windows (within ``masks`` if given)."""
    m = (masks.float() if masks is not None else torch.ones_like(grey))[:, None]
    box = lambda x: F.avg_pool2d(F.pad(x, (r, r, r, r)), 2 * r + 1, 1)
    n = box(m).clamp_min(1e-6)
    mu, mu2 = box(grey[:, None] * m) / n, box(grey[:, None] ** 2 * m) / n
    return (mu2 - mu * mu).clamp_min(0).sqrt()[:, 0]


def _fit2(cols, a, b, m, bins=48, bw=0.05, prior_px=50.0, top=0.25):
    """Nadaraya-Watson table ``[bins, bins, 3]`` of ``E[rgb | a, b / top]`` (Gaussian kernel ``bw`` in each),
    shrunk towards the mean colour as :func:`arcsem.colorize.prior.fit_grey_prior`."""
    c, a, b = cols[m].double(), a[m].double().clamp(0, 1), (b[m].double() / top).clamp(0, 1)
    idx = (a * bins).long().clamp_max(bins - 1) * bins + (b * bins).long().clamp_max(bins - 1)
    cnt = torch.zeros(bins * bins, dtype=torch.float64).index_add_(0, idx, torch.ones_like(a)).reshape(bins, bins)
    sm = torch.zeros(bins * bins, 3, dtype=torch.float64).index_add_(0, idx, c).reshape(bins, bins, 3)
    ctr = (torch.arange(bins, dtype=torch.float64) + 0.5) / bins
    K = torch.exp(-((ctr[:, None] - ctr[None]) ** 2) / (2 * bw ** 2))
    w, s = K @ cnt @ K.T, torch.einsum("ij,jkc,lk->ilc", K, sm, K)
    return ((s + prior_px * c.mean(0)) / (w + prior_px)[..., None]).float().clamp(0, 1)


def texture(run: Path, refs_spec: str) -> str:
    from arcsem.colorize.prior import fit_grey_prior, grey_prior

    s = setup(run, refs_spec)
    grey, masks, ridx, refs, out, gt = s["grey"], s["masks"], s["ridx"], s["refs"], s["outside"], s["gt"]
    lut = fit_grey_prior(refs.images, grey[ridx], masks[ridx])
    line = f"{run.name} {refs_spec}: grey prior {_db(grey_prior(lut, grey), gt, out):.2f}"
    for name, within in (("grey + std in the mask", masks), ("grey + std", None)):
        std, bins = _local_std(grey, within), 48
        tab = _fit2(refs.images.float(), grey[ridx], std[ridx], masks[ridx], bins=bins)
        ia = (grey.clamp(0, 1) * bins).long().clamp_max(bins - 1)
        ib = ((std / 0.25).clamp(0, 1) * bins).long().clamp_max(bins - 1)
        line += f" | {name} {_db(tab[ia, ib], gt, out):.2f}"
    return line


def _support(cams, depth, tol):
    """Per pixel: other views agreeing with its point's depth within ``tol`` footprints, and views where the point
    lies in front of their surface by more (free-space violations)."""
    N, H, W = depth.shape
    pts, fx = cams.unproject(depth), cams.K[:, 0, 0]
    sup, vio = torch.zeros(N, H, W, dtype=torch.int32), torch.zeros(N, H, W, dtype=torch.int32)
    for v in range(N):
        ok = depth[v] > 0
        uv, z = cams.project(pts[v][ok])
        u, w = uv[..., 0].round().long(), uv[..., 1].round().long()
        inside = (u >= 0) & (u < W) & (w >= 0) & (w < H) & (z > 0)
        db = depth[torch.arange(N)[:, None], w.clamp(0, H - 1), u.clamp(0, W - 1)]
        has = inside & (db > 0)
        has[v] = False
        fp = db / fx[:, None]
        sup[v][ok] = (has & ((z - db).abs() <= tol * fp)).sum(0).int()
        vio[v][ok] = (has & (z < db - tol * fp)).sum(0).int()
    return sup, vio


def filters(run: Path, refs_spec: str) -> str:
    from arcsem.colorize.surface import surface_colors

    s = setup(run, refs_spec)
    split, masks, ridx, refs, out, gt, grey = (s[k] for k in ("split", "masks", "ridx", "refs", "outside", "gt",
                                                             "grey"))
    md, mn = s["geo"].value
    ed, al, dist = [], [], []
    with torch.no_grad():
        for i in range(len(split)):
            o = s["backbone"].render(split.cameras[i:i + 1])
            ed.append(o["depth"][..., 0].cpu())
            al.append(o["alpha"][..., 0].cpu())
            dist.append(o["distortion"][..., 0].cpu())
    ed, al, dist = torch.cat(ed), torch.cat(al), torch.cat(dist)
    fx = split.cameras.K[:, 0, 0].float()
    fp = (md / fx[:, None, None]).clamp_min(1e-9)
    ok = masks & (md > 0)
    gross = ok & ((md - split.depths.float()).abs() / (split.depths.float() / fx[:, None, None]) > 10)
    sup, vio = _support(split.cameras, md, 2.0)
    drops = {"none": torch.zeros_like(ok), "support < 2": ok & (sup < 2), "violations": ok & (vio > 0)}
    for name, score in (("depth gap", (ed / al.clamp_min(1e-6) - md).abs() / fp), ("distortion", dist.sqrt() / fp),
                        ("transparency", 1 - al)):
        for q in (0.8, 0.9):
            drops[f"{name} top {round(100 * (1 - q))} %"] = ok & (score > torch.quantile(score[ok][::7], q))
    line = f"{run.name} {refs_spec}:"
    for name, bad in drops.items():
        cols, valid, _ = surface_colors(split.cameras, torch.where(bad, torch.zeros_like(md), md), masks, grey, mn,
                                        ridx, refs.images.float(), s["cc"].surface)
        sel = out & valid
        line += (f" | {name}: catches {float((gross & bad).sum() / gross.sum().clamp_min(1)):.2f} -> reach "
                 f"{float(sel.sum() / out.sum()):.2f}, {_db(cols, gt, sel):.2f}")
    return line


def gap_target(run: Path, refs_spec: str) -> str:
    """The target outside the coverage (the 2-D pseudo-colours, then the spread where confident, unshaded, then the
    prior) with the spread's graph on all model-depth pixels or without the 10/20 % of largest expected-median gap."""
    from arcsem.colorize import inputs as prep
    from arcsem.colorize.surface import surface_colors

    s = setup(run, refs_spec)
    cc, split, masks, ridx, refs, out, gt, grey = (s[k] for k in ("cc", "split", "masks", "ridx", "refs", "outside",
                                                                   "gt", "grey"))
    off_cc = dataclasses.replace(cc, surface=dataclasses.replace(cc.surface, mode="off"))
    off, _, info = prep.pseudo_target(off_cc, s["cfg"], s["ckpt"], s["backbone"], split, masks, refs, CACHE, s["geo"])
    v2 = info["valid2d"].bool()
    md, mn = s["geo"].value
    ed, al = [], []
    with torch.no_grad():
        for i in range(len(split)):
            o = s["backbone"].render(split.cameras[i:i + 1])
            ed.append(o["depth"][..., 0].cpu())
            al.append(o["alpha"][..., 0].cpu())
    ed, al = torch.cat(ed), torch.cat(al)
    fp = (md / split.cameras.K[:, 0, 0].float()[:, None, None]).clamp_min(1e-9)
    ok = masks & (md > 0)
    gap = (ed / al.clamp_min(1e-6) - md).abs() / fp
    carried = torch.cat([refs.images.float(), grey[ridx][..., None]], -1)
    line = f"{run.name} {refs_spec}: spread off {_db(off, gt, out):.2f}"
    for name, q in (("all pixels", None), ("gap top 20 % out", 0.8), ("gap top 10 % out", 0.9)):
        d = md if q is None else torch.where(ok & (gap > torch.quantile(gap[ok][::7], q)), torch.zeros_like(md), md)
        cols, valid, _ = surface_colors(split.cameras, d, masks, grey, mn, ridx, carried, cc.surface)
        line += f" | {name} {_db(torch.where((valid & ~v2)[..., None], cols[..., :3], off), gt, out):.2f}"
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("probe", choices=("confidence", "texture", "filters", "gap_target"))
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--references", nargs="+", default=["one", "three"])
    args = ap.parse_args()
    probe = {"confidence": confidence, "texture": texture, "filters": filters, "gap_target": gap_target}[args.probe]
    for run in args.runs:
        for refs in args.references:
            print(probe(run, refs), flush=True)


if __name__ == "__main__":
    main()
