"""TCM guidance and CCM targets (Ref-NPR, as used by ArCSEM), computed once per view and cached.

Both depend only on the grey images and the references, never on the render:

* TCM: for each feature location of the grey view ``g`` (per block of the feature extractor,
  ``colorize.features``), the nearest feature by cosine distance among the grey references' features
  (all references concatenated); the guidance is the COLOUR reference at that location in the TCM
  loss space (its VGG feature, as in the paper, or its colour: :mod:`arcsem.colorize.features`).
  Stored as match indices into the flattened reference loss-space features (``[h, w]`` long per
  block), gathered when a batch needs them.
* CCM: the same search on block-0 (VGG: relu3_x) features pooled to cells of ``ccm_downscale`` pixels (with the
  default ``tcm_downscale`` 4 a block-3 location IS a 16-pixel cell); a match counts if its cosine
  distance is <= ``ccm_max_dist`` (0.6) and its reference patch is not white (all channels > 0.99);
  the target is the mean colour of the matched reference patch.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..imageops import downscale, patch_means
from .pseudocolor import cache_key

__all__ = ["Guidance", "ccm_match", "ccm_targets", "cell_colours", "nearest_cosine", "tcm_match"]

log = logging.getLogger(__name__)


def nearest_cosine(query: Tensor, keys: Tensor, chunk: int = 4096) -> tuple[Tensor, Tensor]:
    """Nearest key by cosine distance: query ``[Q, D]``, keys ``[K, D]`` -> index ``[Q]``, distance ``[Q]``."""
    kn = F.normalize(keys.float(), dim=-1, eps=1e-8)
    idx = torch.empty(len(query), dtype=torch.long)
    dist = torch.empty(len(query))
    for s in range(0, len(query), chunk):
        qn = F.normalize(query[s:s + chunk].float(), dim=-1, eps=1e-8)
        best, arg = (qn @ kn.T).max(-1)
        idx[s:s + chunk], dist[s:s + chunk] = arg, 1.0 - best
    return idx, dist


def _flat(feats: Tensor) -> Tensor:
    """``[R, D, h, w]`` -> ``[R*h*w, D]`` (reference-major, then row-major locations)."""
    return feats.permute(0, 2, 3, 1).reshape(-1, feats.shape[1])


def tcm_match(view_feats: list[Tensor], ref_gray_feats: list[Tensor], chunk: int = 4096) -> list[Tensor]:
    """Per block: view features ``[D, h, w]``, reference grey features ``[R, D, h', w']`` -> index ``[h, w]``."""
    out = []
    for vf, rf in zip(view_feats, ref_gray_feats):
        D, h, w = vf.shape
        idx, _ = nearest_cosine(vf.reshape(D, -1).T, _flat(rf), chunk)
        out.append(idx.reshape(h, w))
    return out


def _pool_to(feats: Tensor, grid: tuple[int, int]) -> Tensor:
    """``[C, D, h, w]`` -> ``[C, D, *grid]`` by adaptive average pooling (identity when equal)."""
    return feats if tuple(feats.shape[-2:]) == tuple(grid) else F.adaptive_avg_pool2d(feats, grid)


def cell_colours(images: Tensor, grid: tuple[int, int]) -> Tensor:
    """``[N*h*w, 3]``: images ``[N, H, W, 3]`` pooled to ``grid`` (area means), view-major then row-major: the colour
    of each location of a feature grid, as a TCM match brings it."""
    return _flat(_pool_to(images.permute(0, 3, 1, 2).float(), grid))


def ccm_match(view_feat: Tensor, ref_gray_feat: Tensor, grid: tuple[int, int], chunk: int = 4096):
    """Cell matches: view block feature ``[D, h, w]``, references ``[R, D, h, w]`` pooled to ``grid``.

    Returns index ``[hc, wc]`` into the flattened reference cells and cosine distance ``[hc, wc]``.
    """
    q = _pool_to(view_feat[None], grid)[0]
    idx, dist = nearest_cosine(q.reshape(q.shape[0], -1).T, _flat(_pool_to(ref_gray_feat, grid)), chunk)
    return idx.reshape(grid), dist.reshape(grid)


def ccm_targets(idx: Tensor, dist: Tensor, ref_means: Tensor, max_dist: float = 0.6, white: float = 0.99):
    """CCM targets: ``ref_means [R*hc*wc, 3]`` gathered at ``idx [hc, wc]``; valid where the match is
    close enough (``dist <= max_dist``) and the patch is not white (not all channels > ``white``)."""
    target = ref_means[idx]
    valid = (dist <= max_dist) & ~(target > white).all(-1)
    return target, valid


class Guidance:
    """TCM match indices and CCM targets of every view, computed on first use and cached in memory and on disk.

    Args:
        extractor: matches grey images (:class:`arcsem.colorize.features.Extractor`). space: the TCM loss
            space (the extractor itself, or :class:`~arcsem.colorize.features.ColourSpace`); its blocks have the
            extractor's grids. gray: ``[N, H, W, 3]`` grey training images.
        ref_indices: ``R`` view indices of the references. ref_colors: ``[R, H, W, 3]``.
        tcm_downscale: images scaled down by this before the extractor (paper: 4). ccm_downscale: CCM cell (16).
    """

    def __init__(self, extractor, space, gray: Tensor, ref_indices, ref_colors: Tensor, tcm_downscale: int = 4,
                 ccm_downscale: int = 16, ccm_max_dist: float = 0.6, ccm_white: float = 0.99,
                 cache_dir: str | Path | None = None, chunk: int = 1024, geometry: Tensor | None = None,
                 guard=None):
        self.extractor, self.space, self.gray, self.ref_indices = extractor, space, gray, list(ref_indices)
        # guarded matching (arcsem.colorize.guard): geometry [N, G, H, W] descriptors of every view, guard a GuardConfig
        self.geometry = geometry if guard is not None and guard.enabled else None
        self.guard = guard
        self.tcm_downscale, self.ccm_downscale = tcm_downscale, ccm_downscale
        self.ccm_max_dist, self.ccm_white, self.chunk = ccm_max_dist, ccm_white, chunk
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.grid = (gray.shape[1] // ccm_downscale, gray.shape[2] // ccm_downscale)
        with torch.no_grad():
            self.ref_color = [_flat(f) for f in space(downscale(ref_colors.float(), tcm_downscale))]
        self._ref_gray: list[Tensor] | None = None  # extractor features of the grey references, when needed
        self.ref_means = patch_means(ref_colors.float(), ccm_downscale).reshape(-1, 3)
        self.ref_rgb = ref_colors.float()  # [R, H, W, 3]: the colour a match brings, for the agreement test
        self._agree: dict[tuple[int, str], Tensor] = {}  # (view, "ccm"|"tcm<b>") -> [h, w] bool (agree())
        self._ref_rgb_at: dict[tuple[int, int], Tensor] = {}  # grid -> [R*h*w, 3] reference colours pooled to it
        from .features.base import space_label

        # the matches depend on the tests' tolerances, not on where the losses later act (uncovered_only, check)
        matching = {k: v for k, v in vars(guard).items() if k not in ("uncovered_only", "check")} if guard else {}
        guard_key = () if self.geometry is None else ("guard-v1", self.geometry, sorted(matching.items()))
        self.key = cache_key("guidance-v2", extractor.key(), space_label(space), gray,
                             self.ref_indices, ref_colors, tcm_downscale, ccm_downscale, ccm_max_dist, ccm_white,
                             *guard_key)
        self._memory: dict[int, dict[str, Tensor]] = {}

    def to(self, device) -> Guidance:
        """Move everything held to ``device``: the reference colours and the matches computed so far, which
        :meth:`targets` gathers from during training (compute every view's matches first), the grey views and the
        extractor (a module)."""
        self.ref_color = [t.to(device) for t in self.ref_color]
        self.ref_means, self.gray, self.ref_rgb = self.ref_means.to(device), self.gray.to(device), self.ref_rgb.to(device)
        self._ref_rgb_at = {}
        if self._ref_gray is not None:
            self._ref_gray = [t.to(device) for t in self._ref_gray]
        if self.geometry is not None:
            self.geometry = self.geometry.to(device)
        self._memory = {v: {k: t.to(device) for k, t in m.items()} for v, m in self._memory.items()}
        self._agree = {k: t.to(device) for k, t in self._agree.items()}
        if isinstance(self.extractor, torch.nn.Module):
            self.extractor.to(device)
        return self

    def without(self, r: int) -> Guidance:
        """The guidance of the same views with reference ``r`` (a position in ``ref_indices``) left out, sharing
        this one's features (nothing recomputed; kept in memory only): for holding references out in turn."""
        import copy

        keep = [i for i in range(len(self.ref_indices)) if i != r]
        out = copy.copy(self)
        out.ref_indices = [self.ref_indices[i] for i in keep]
        R = len(self.ref_indices)
        out.ref_color = [rc.reshape(R, -1, rc.shape[1])[keep].reshape(-1, rc.shape[1]) for rc in self.ref_color]
        out.ref_means = self.ref_means.reshape(R, -1, 3)[keep].reshape(-1, 3)
        out.ref_rgb, out._agree, out._ref_rgb_at = self.ref_rgb[keep], {}, {}
        out._ref_gray = [f[keep] for f in self.ref_gray]
        out.cache_dir, out._memory, out.key = None, {}, f"{self.key}-without{r}"
        return out

    def features(self, images: Tensor) -> list[Tensor]:
        """Extractor block features of images ``[C, H, W, 3]`` after the TCM downscale (no gradient)."""
        from .features.base import no_grad_features

        return no_grad_features(self.extractor, downscale(images.float(), self.tcm_downscale))

    @property
    def ref_gray(self) -> list[Tensor]:
        """Per block ``[R, D_b, h_b, w_b]``: the grey references' features (computed on the first cache miss)."""
        if self._ref_gray is None:
            self._ref_gray = self.features(self.gray[self.ref_indices])
        return self._ref_gray

    def _compute(self, v: int) -> dict[str, Tensor]:
        feats = [f[0] for f in self.features(self.gray[v:v + 1])]
        if self.geometry is not None:
            return self._compute_guarded(v, feats)
        out = {f"tcm_idx{b}": i for b, i in enumerate(tcm_match(feats, self.ref_gray, self.chunk))}
        out["ccm_idx"], out["ccm_dist"] = ccm_match(feats[0], self.ref_gray[0], self.grid, self.chunk)
        return out

    def _geo(self, views: list[int], grid: tuple[int, int]) -> Tensor:
        """``[len(views)*h*w, G]`` geometry descriptors of ``views`` at a feature grid (nearest sample; NaN kept)."""
        g = F.interpolate(self.geometry[views].float(), size=grid, mode="nearest")
        return g.permute(0, 2, 3, 1).reshape(-1, g.shape[1])

    def _points(self, points: Tensor, views: list[int], grid: tuple[int, int]) -> Tensor:
        """``[len(views)*h*w, 3]`` world points ``points [N, H, W, 3]`` of ``views`` at a feature grid (nearest)."""
        p = F.interpolate(points[views].permute(0, 3, 1, 2).float(), size=grid, mode="nearest")
        return p.permute(0, 2, 3, 1).reshape(-1, 3)

    def _compute_guarded(self, v: int, feats: list[Tensor], apart: tuple[Tensor, float, float] | None = None
                         ) -> dict[str, Tensor]:
        """As the plain search, among geometrically compatible locations, with the ratio and mutual tests
        (:func:`arcsem.colorize.guard.guarded_nearest`): adds ``tcm_ok<b>`` ``[h_b, w_b]`` and ``ccm_ok [hc, wc]``.
        ``apart``: ``(points [N, H, W, 3], pixel footprint, factor)``: only keys farther than ``factor`` cells (a
        cell's world size: the footprint times the pixels a cell spans) from the location's own surface point."""
        from .guard import grid_positions, guarded_nearest

        out = {}
        pairs = [(f, r, f"tcm_idx{b}", f"tcm_ok{b}") for b, (f, r) in enumerate(zip(feats, self.ref_gray))]
        pairs.append((_pool_to(feats[0][None], self.grid)[0], _pool_to(self.ref_gray[0], self.grid), "ccm_idx",
                      "ccm_ok"))
        for f, r, name, ok_name in pairs:
            D, h, w = f.shape
            near = None
            if apart is not None:
                points, foot, factor = apart
                near = (self._points(points, [v], (h, w)), self._points(points, self.ref_indices, tuple(r.shape[-2:])),
                        factor * foot * self.gray.shape[1] / h)
            idx, dist, ok = guarded_nearest(
                f.reshape(D, -1).T, _flat(r), self._geo([v], (h, w)), self._geo(self.ref_indices, tuple(r.shape[-2:])),
                grid_positions(1, h, w)[:, 1:], grid_positions(*r.shape[:1], *r.shape[-2:]), self.guard, self.chunk,
                near)
            out[name], out[ok_name] = idx.reshape(h, w), ok.reshape(h, w)
            if name == "ccm_idx":
                out["ccm_dist"] = dist.reshape(h, w)
        return out

    def matches(self, v: int) -> dict[str, Tensor]:
        """Match indices of view ``v``: ``tcm_idx<b>`` ``[h_b, w_b]``, ``ccm_idx``/``ccm_dist`` ``[hc, wc]``."""
        if v in self._memory:
            return self._memory[v]
        path = self.cache_dir / f"guide_{self.key}_{v}.npz" if self.cache_dir else None
        if path is not None and path.exists():
            with np.load(path) as z:
                out = {k: torch.from_numpy(z[k]) for k in z.files}
        else:
            out = self._compute(v)
            if path is not None:
                _atomic_savez(path, {k: t.numpy() for k, t in out.items()})
        self._memory[v] = out
        return out

    def apart_matches(self, v: int, points: Tensor, footprint: float, factor: float) -> dict[str, Tensor]:
        """View ``v``'s guarded matches (as :meth:`matches`) searched only among the reference locations more than
        ``factor`` cells from each location's own surface point (``points [N, H, W, 3]``, world; ``footprint``: a
        pixel's world size): what a point no reference sees gets, asked where the answer is known
        (:func:`arcsem.colorize.guard.match_check`). Computed each call, not cached; needs the guard."""
        feats = [f[0] for f in self.features(self.gray[v:v + 1])]
        return self._compute_guarded(v, feats, (points, footprint, factor))

    def targets(self, v: int, matches: dict[str, Tensor] | None = None) -> dict[str, Tensor | list[Tensor]]:
        """``tcm_guidance``: per block ``[D_b, h_b, w_b]`` (loss space); ``ccm_target [hc, wc, 3]``, ``ccm_valid [hc, wc]``
        (``matches``: another match set of ``v``, :meth:`apart_matches`, without the cross-view agreement test)."""
        m = self.matches(v) if matches is None else matches
        agree = self._agree if matches is None else {}
        guide = []
        for b, rc in enumerate(self.ref_color):
            idx = m[f"tcm_idx{b}"]
            guide.append(rc[idx.reshape(-1)].T.reshape(rc.shape[1], *idx.shape))
        target, valid = ccm_targets(m["ccm_idx"], m["ccm_dist"], self.ref_means, self.ccm_max_dist, self.ccm_white)
        out = {"tcm_guidance": guide, "ccm_target": target,
               "ccm_valid": valid & m.get("ccm_ok", True) & agree.get((v, "ccm"), True)}
        if "tcm_ok0" in m:
            out["tcm_valid"] = [m[f"tcm_ok{b}"] & agree.get((v, f"tcm{b}"), True) for b in range(len(guide))]
        return out

    def kinds(self) -> list[tuple[str, tuple[int, int]]]:
        """The match kinds and their grids: ``("ccm", (hc, wc))``, then ``("tcm<b>", (h_b, w_b))`` per block."""
        return [("ccm", self.grid)] + [(f"tcm{b}", tuple(r.shape[-2:])) for b, r in enumerate(self.ref_gray)]

    def carried(self, v: int, name: str, matches: dict[str, Tensor] | None = None) -> tuple[Tensor, Tensor]:
        """The colour each match of kind ``name`` brings to view ``v`` (``[h*w, 3]``: the CCM target, or the
        reference colour at the TCM match, pooled to the block's grid) and which matches are kept (``[h*w]``)
        (``matches``: as :meth:`targets`)."""
        t, m = self.targets(v, matches), self.matches(v) if matches is None else matches
        if name == "ccm":
            return t["ccm_target"].reshape(-1, 3), t["ccm_valid"].reshape(-1)
        b = int(name[3:])
        grid = tuple(self.ref_gray[b].shape[-2:])
        if grid not in self._ref_rgb_at:  # pooled once per grid, not once per view
            self._ref_rgb_at[grid] = cell_colours(self.ref_rgb, grid)
        rgb = self._ref_rgb_at[grid]
        idx = m[f"tcm_idx{b}"].reshape(-1)
        keep = t["tcm_valid"][b].reshape(-1) if "tcm_valid" in t else torch.ones(len(idx), dtype=torch.bool)
        return rgb[idx], keep

    def agree(self, points: Tensor, footprint: float, tol: float) -> dict[str, float]:
        """Drop the guarded matches whose colour disagrees with the other views' at the same surface point
        (:func:`arcsem.colorize.guard.cross_view_agreement`), once every view's matches exist.

        Args: points ``[N, H, W, 3]`` world point of every pixel of every view (NaN: no surface); footprint: the
            world size of a pixel; tol: the largest channel difference from a point's median colour.
        Returns: the share of the kept matches dropped, per kind (``ccm``, ``tcm<b>``).
        """
        from .guard import cross_view_agreement

        N, H = points.shape[0], points.shape[1]
        dropped = {}
        for name, grid in self.kinds():
            pts = F.interpolate(points.permute(0, 3, 1, 2).float(), size=grid, mode="nearest")
            pts = pts.permute(0, 2, 3, 1).reshape(N, -1, 3)
            carried = [self.carried(v, name) for v in range(N)]
            cols, keep = [c for c, _ in carried], [k for _, k in carried]
            ok = cross_view_agreement(list(pts), cols, keep, footprint * H / grid[0], tol)
            for v in range(N):
                self._agree[(v, name)] = ok[v].reshape(grid)
            before = sum(int(k.sum()) for k in keep)
            dropped[name] = 1.0 - sum(int(o.sum()) for o in ok) / max(before, 1)
        return dropped


def _atomic_savez(path: Path, arrays: dict) -> None:
    from ..files import atomic_open

    with atomic_open(path, "wb") as f:
        np.savez(f, **arrays)
