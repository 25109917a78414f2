"""``learned``: a small CNN trained on the scene's own grey views, so that its features are view-invariant
for this specimen. No pretrained weights.

Training (:func:`train_scene_cnn`): after stage 1 the geometry is known, so the pixel correspondences
between two training views follow from the stage-1 depth and the cameras (:mod:`.correspond`). Each
step takes a view ``a`` and one of its ``neighbours`` nearest views ``b`` (by viewing direction), crops
at most ``crop x crop`` pixels around a random specimen pixel of ``a`` and around where it lands in
``b``, samples ``points`` correspondences inside both crops and applies a symmetric InfoNCE loss
(temperature ``tau``) per block: the feature at a pixel of ``a`` must be nearer (cosine) to the feature
at its corresponding pixel of ``b`` than to those at the other sampled pixels of ``b``. Images enter as
standardised grey (exposure drift cancels). Everything is drawn from generators seeded with the run's
seed, so a model is a function of (views, depth, cameras, masks, seed, settings) and is cached under
that key (``<cache>/features/learned_<key>.pt``, tensors only).
"""
from __future__ import annotations

import logging
import os
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..pseudocolor import cache_key
from .base import SceneContext, grey_channel
from .correspond import correspondences, downscale_geometry

__all__ = ["LearnedConfig", "LearnedFeatures", "SceneCNN", "info_nce", "learned_extractor", "train_scene_cnn"]

log = logging.getLogger(__name__)
FORMAT = "arcsem-learned-features-v1"


@dataclass(frozen=True)
class LearnedConfig:
    """Settings of the scene CNN (all part of its cache key)."""

    width: int = 32         # channels of the stride-2 stage; 2x at strides 4 and 8
    dim: int = 64           # feature dimension of each block
    steps: int = 300
    lr: float = 2e-3
    points: int = 256       # correspondences per step
    crop: int = 40          # crop size (pixels of the TCM input): bounds a step's cost; smaller than the image, so
                            # the CNN cannot tell image positions (measured: benchmarks/feature_matching.py)
    neighbours: int = 10    # partner view b among the nearest views of a (wider baselines than 4 matched better)
    tau: float = 0.1        # InfoNCE temperature


class SceneCNN(nn.Module):
    """``x [N, 1, H, W]`` standardised grey -> ``[[N, dim, H // 4, W // 4], [N, dim, H // 8, W // 8]]``."""

    strides = (4, 8)

    def __init__(self, width: int = 32, dim: int = 64):
        super().__init__()
        c1, c2 = width, 2 * width

        def conv(i, o, s=1, d=1):
            return nn.Conv2d(i, o, 3, stride=s, padding=d, dilation=d)

        self.s4 = nn.Sequential(nn.Conv2d(1, c1, 5, stride=2, padding=2), nn.ReLU(), conv(c1, c1), nn.ReLU(),
                                conv(c1, c2, 2), nn.ReLU(), conv(c2, c2, d=2), nn.ReLU())
        self.s8 = nn.Sequential(conv(c2, c2, 2), nn.ReLU(), conv(c2, c2, d=2), nn.ReLU())
        self.head4, self.head8 = nn.Conv2d(c2, dim, 1), nn.Conv2d(c2, dim, 1)

    def forward(self, x: Tensor) -> list[Tensor]:
        H, W = x.shape[-2:]
        a = self.s4(x)
        b = self.s8(a)
        return [self.head4(a)[..., : H // 4, : W // 4], self.head8(b)[..., : H // 8, : W // 8]]


def sample_features(feat: Tensor, uv: Tensor, stride: int) -> Tensor:
    """Bilinear features ``[M, D]`` of one map ``[D, h, w]`` at pixel coordinates ``uv [M, 2]`` of its input."""
    _, h, w = feat.shape
    fx = (uv[:, 0] - stride / 2.0) / stride  # cell j is centred on pixel coordinate s*j + s/2
    fy = (uv[:, 1] - stride / 2.0) / stride
    grid = torch.stack([2 * fx / max(w - 1, 1) - 1, 2 * fy / max(h - 1, 1) - 1], -1)
    out = F.grid_sample(feat[None], grid[None, None], mode="bilinear", padding_mode="border", align_corners=True)
    return out[0, :, 0].T


def info_nce(fa: Tensor, fb: Tensor, tau: float) -> Tensor:
    """Symmetric InfoNCE of matched rows ``fa, fb [M, D]`` (row i of each is a positive pair)."""
    fa, fb = F.normalize(fa, dim=-1), F.normalize(fb, dim=-1)
    logits = fa @ fb.T / tau
    target = torch.arange(len(fa))
    return 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))


def _crop_box(cx: float, cy: float, size: int, H: int, W: int) -> tuple[int, int, int, int]:
    """``(x0, y0, w, h)`` of a crop of at most ``size`` around ``(cx, cy)``, inside the image."""
    w, h = min(size, W), min(size, H)
    x0 = int(min(max(round(cx - w / 2), 0), W - w))
    y0 = int(min(max(round(cy - h / 2), 0), H - h))
    return x0, y0, w, h


def _neighbours(cams, k: int) -> Tensor:
    """``[N, k]`` the ``k`` views nearest in viewing direction to each view (itself excluded)."""
    d = cams.forward.double()
    sim = d @ d.T - 3 * torch.eye(len(d), dtype=d.dtype)
    return sim.topk(min(k, len(d) - 1), dim=-1).indices


def _step_pairs(g: torch.Generator, cams, depths, masks, cfg: LearnedConfig, nbr: Tensor):
    """One step's views, crops and correspondences (or None when the draw found too few)."""
    N, H, W = depths.shape
    a = int(torch.randint(N, (1,), generator=g))
    b = int(nbr[a, int(torch.randint(nbr.shape[1], (1,), generator=g))])
    cand = (masks[a] & (depths[a] > 0)).nonzero()
    if len(cand) < 16:
        return None
    cy, cx = (cand[int(torch.randint(len(cand), (1,), generator=g))].double() + 0.5).tolist()
    box_a = _crop_box(cx, cy, cfg.crop, H, W)
    x0, y0, w, h = box_a
    inside = cand[(cand[:, 1] >= x0) & (cand[:, 1] < x0 + w) & (cand[:, 0] >= y0) & (cand[:, 0] < y0 + h)]
    pick = inside[torch.randperm(len(inside), generator=g)[: 4 * cfg.points]].flip(-1)
    uv_a, uv_b, _ = correspondences(cams, depths, masks, a, b, pick)
    if len(uv_a) < 16:
        return None
    mid = uv_b.median(0).values.tolist()
    box_b = _crop_box(mid[0], mid[1], cfg.crop, H, W)
    keep = ((uv_b[:, 0] >= box_b[0]) & (uv_b[:, 0] < box_b[0] + box_b[2])
            & (uv_b[:, 1] >= box_b[1]) & (uv_b[:, 1] < box_b[1] + box_b[3]))
    uv_a, uv_b = uv_a[keep][: cfg.points], uv_b[keep][: cfg.points]
    if len(uv_a) < 16:
        return None
    return a, b, box_a, box_b, uv_a, uv_b


def _crop(x: Tensor, box) -> Tensor:
    x0, y0, w, h = box
    return x[..., y0:y0 + h, x0:x0 + w]


def train_scene_cnn(gray: Tensor, cams, depths: Tensor, masks: Tensor, cfg: LearnedConfig, seed: int = 0,
                    progress: bool = False) -> tuple[SceneCNN, dict]:
    """Train :class:`SceneCNN` on grey views ``[N, H, W, 3]`` with their cameras, depth ``[N, H, W]`` and masks
    (all at the TCM input resolution); returns the model (eval mode) and ``{"steps", "loss_first", "loss_last",
    "time_s"}``."""

    t0 = time.perf_counter()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = SceneCNN(cfg.width, cfg.dim)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # many small ops: one thread is faster, and never spin-waits on a busy machine
    try:
        losses = _train_loop(net, gray, cams, depths, masks, cfg, seed, progress)
    finally:
        torch.set_num_threads(threads)
    net.eval().requires_grad_(False)
    if not losses:
        from ...errors import DataError

        raise DataError("colorize.features=learned: no pixel correspondences between the training views "
                        "(empty masks or depth?)")
    n = max(1, len(losses) // 10)
    info = {"steps": len(losses), "loss_first": sum(losses[:n]) / n, "loss_last": sum(losses[-n:]) / n,
            "time_s": time.perf_counter() - t0}
    return net, info


def _train_loop(net: SceneCNN, gray, cams, depths, masks, cfg: LearnedConfig, seed: int, progress: bool) -> list:
    """The InfoNCE steps of :func:`train_scene_cnn`; returns the loss of each step that found correspondences."""
    from tqdm.auto import tqdm

    g = torch.Generator().manual_seed(seed)
    x = grey_channel(gray)
    nbr = _neighbours(cams, cfg.neighbours)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    losses = []
    for _ in tqdm(range(cfg.steps), desc="scene features", disable=not progress, leave=False):
        draw = _step_pairs(g, cams, depths, masks, cfg, nbr)
        if draw is None:
            continue
        a, b, box_a, box_b, uv_a, uv_b = draw
        fa, fb = net(_crop(x[a:a + 1], box_a)), net(_crop(x[b:b + 1], box_b))
        off_a = torch.tensor(box_a[:2], dtype=uv_a.dtype)
        off_b = torch.tensor(box_b[:2], dtype=uv_b.dtype)
        loss = sum(info_nce(sample_features(fa[k][0], uv_a - off_a, s), sample_features(fb[k][0], uv_b - off_b, s),
                            cfg.tau) for k, s in enumerate(net.strides))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return losses


class LearnedFeatures:
    """A trained :class:`SceneCNN` as an extractor: ``images [N, H, W, 3]`` -> per block ``[N, dim, H // s, W // s]``."""

    name = "learned"
    differentiable = False  # trained on grey structure: on a colour render it would not describe colour

    def __init__(self, net: SceneCNN, model_key: str, info: dict):
        self.net, self.model_key, self.info = net, model_key, info
        self.strides = SceneCNN.strides

    def key(self) -> str:
        return f"learned:{self.model_key}"

    def label(self) -> str:
        return "learned"

    def __call__(self, images: Tensor) -> list[Tensor]:
        with torch.no_grad():
            return self.net(grey_channel(images))


def _save(path: Path, net: SceneCNN, cfg: LearnedConfig, info: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    os.close(fd)
    try:
        torch.save({"format": FORMAT, "config": asdict(cfg), "info": info, "state_dict": net.state_dict()}, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load(path: Path, cfg: LearnedConfig) -> tuple[SceneCNN, dict] | None:
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
        if blob.get("format") != FORMAT:
            return None
        net = SceneCNN(cfg.width, cfg.dim)
        net.load_state_dict(blob["state_dict"])
    except (OSError, RuntimeError, KeyError, AttributeError) as exc:  # unreadable cache: retrain
        log.warning("scene-feature cache %s unreadable (%s); retraining", path, exc)
        return None
    return net.eval().requires_grad_(False), dict(blob.get("info") or {})


def learned_extractor(ctx: SceneContext, cfg: LearnedConfig | None = None) -> LearnedFeatures:
    """The scene CNN of ``ctx``: read from ``<cache>/features/learned_<key>.pt`` or trained (and cached)."""
    cfg = cfg or LearnedConfig()
    f = ctx.downscale
    cams = ctx.cameras.scaled(1.0 / f) if f != 1 else ctx.cameras
    key = cache_key(FORMAT, asdict(cfg), ctx.seed, f, ctx.gray, ctx.masks, ctx.depth_key, cams.world_to_cam, cams.K,
                    cams.model)
    path = Path(ctx.cache_dir) / "features" / f"learned_{key}.pt" if ctx.cache_dir else None
    if path is not None and path.exists():
        hit = _load(path, cfg)
        if hit is not None:
            return LearnedFeatures(hit[0], key, {**hit[1], "cache_hit": True})
    from ...imageops import downscale

    depths, masks = downscale_geometry(ctx.depths().float(), ctx.masks.bool(), f)
    gray = downscale(ctx.gray.float(), f)
    net, info = train_scene_cnn(gray, cams, depths, masks, cfg, ctx.seed, ctx.progress)
    log.info("scene features: %d steps in %.1f s, InfoNCE %.3f -> %.3f", info["steps"], info["time_s"],
             info["loss_first"], info["loss_last"])
    if path is not None:
        _save(path, net, cfg, info)
    return LearnedFeatures(net, key, {**info, "cache_hit": False})
