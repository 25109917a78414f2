"""The ``plenoxels`` backbone: a sparse SH voxel grid trained on random ray batches (svox2 in PyTorch).

Defaults are the paper's (ArCSEM: 128^3 growing to 304x304x128, 38,400 steps per resolution) and
svox2's (batch 5000 rays, RMSProp beta 0.95, exponential lr decay, init sigma 0.1, SH 0, TV on 1%
of the voxels). :meth:`Plenoxels.learning_rates` and :meth:`Plenoxels.make_optimizers` give the trainer svox2's
schedules and RMSProp.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from ...configs import GroupSchedule
from ...errors import ConfigError
from ...plugins import Backbone
from .background import build_background
from .bounds import grid_bounds
from .config import PlenoxelsConfig
from .fused import max_weights as fused_max_weights
from .fused import resolve_impl
from .grid import build_index, cell_occupancy, occupied_coords, voxel_size
from .optim import SparseRMSprop
from .render import GridData, box_scale, composite, render_grid
from .tv import random_rows, tv_sparse
from .upsample import dilate, max_weights, prune, resample

__all__ = ["Plenoxels"]


def initial_density(cfg: Any, bounds: Tensor, reso: list[int], points: Tensor | None) -> Tensor:
    """``[X*Y*Z]`` starting density: svox2's ``init_sigma`` everywhere; with ``init_points_sigma`` > 0 and a
    point cloud, that value on the voxels within ``init_points_dilate`` voxels of a point (the specimen's
    surface, where 3DGS/2DGS put their first Gaussians) and ``init_sigma`` elsewhere."""
    dens = torch.full(reso, float(cfg.init_sigma))
    if cfg.init_points_sigma <= 0 or points is None or len(points) == 0:
        return dens.reshape(-1)
    g = torch.round((points.float() - bounds[0]) / voxel_size(bounds, reso)).long()
    inside = ((g >= 0) & (g < torch.tensor(reso))).all(-1)
    near = torch.zeros(reso, dtype=torch.bool)
    near[g[inside, 0], g[inside, 1], g[inside, 2]] = True
    near = dilate(near, cfg.init_points_dilate)
    return torch.where(near, float(cfg.init_points_sigma), dens).reshape(-1)


class Plenoxels(Backbone):
    """Sparse voxel grid of density ``[M]`` and SH ``[M, K, 3]`` with an index volume ``[X, Y, Z]``."""

    provides = frozenset({"rgb", "alpha", "depth", "tv", "distortion"})
    batch_mode = "rays"

    Config = PlenoxelsConfig
    export_suffix = ".npz"

    def __init__(self, cfg: Any, scene: Any = None, act: Any = None, **runtime: Any):
        super().__init__(cfg, scene)
        self._check_config(cfg)
        bounds = grid_bounds(scene) if scene is not None else torch.tensor([[-1.0] * 3, [1.0] * 3])
        self.register_buffer("bounds", bounds.clone())
        self.register_buffer("level", torch.tensor(0))
        reso = list(cfg.reso[0])
        index = build_index(torch.ones(reso, dtype=torch.bool))
        self.register_buffer("index", index)
        m, k = int(index.numel()), (cfg.sh_degree + 1) ** 2
        self.density = nn.Parameter(initial_density(cfg, bounds, reso, scene.points if scene is not None else None))
        self.sh = nn.Parameter(torch.full((m, k, 3), float(cfg.init_sh)))
        self.background = build_background(cfg, bounds, scene.train.cameras if scene is not None else None)
        self.__dict__["act"] = act  # owned (and checkpointed) by the trainer, not a submodule
        self.__dict__["_train_cams"] = scene.train.cameras if scene is not None else None
        self._cache: dict[str, Tensor] = {}

    @staticmethod
    def _check_config(cfg: Any) -> None:
        if not cfg.reso or any(len(r) != 3 or min(r) < 2 for r in cfg.reso):
            raise ConfigError(f"backbone 'plenoxels': reso must be a list of [X, Y, Z] with sides >= 2, got {cfg.reso}")

    # ------------------------------------------------------------------ grid access
    @property
    def reso(self) -> list[int]:
        return list(self.index.shape)

    def _cached(self, key: str) -> Tensor:
        if key not in self._cache:
            fn = cell_occupancy if key == "cell_occ" else occupied_coords
            self._cache[key] = fn(self.index)
        return self._cache[key]

    def grid(self) -> GridData:
        return GridData(self.index, self.density, self.sh, self.bounds, self._cached("cell_occ"), self._cached("coords"))

    def num_primitives(self) -> int:
        """Number of stored voxels ``M``."""
        return int(self.density.shape[0])

    def memory_bytes(self) -> int:
        """Bytes of parameters and the index volume."""
        return sum(t.numel() * t.element_size() for t in (self.density, self.sh, self.index))

    # ------------------------------------------------------------------ rendering
    def render_rays(self, rays_o: Tensor, rays_d: Tensor, image_ids: Tensor | None = None, **kw: Any) -> dict:
        """Render rays ``[R, 3]`` (unit camera-z directions) -> ``rgb [R,3]``, ``alpha [R,1]``, ``depth [R,1]``, ``tv []``."""
        out = self._render(rays_o, rays_d, image_ids)
        out.update(self.tv_terms())
        return out

    def _render(self, rays_o: Tensor, rays_d: Tensor, image_ids: Tensor | None, **kw: Any) -> dict:
        c = self.cfg
        if "impl" not in kw:
            kw["impl"] = resolve_impl(c.rasterizer, self.bounds.device)
        o, d = rays_o.to(self.bounds.dtype), rays_d.to(self.bounds.dtype)
        out = render_grid(self.grid(), o, d, sh_degree=c.sh_degree, step_size=c.step_size, stop_thresh=c.stop_thresh,
                          act=self.act, image_ids=image_ids, **kw)
        front, back = self.background(o, d)
        # a learned background is part of the scene (the substrate): ACT transforms it like the grid's samples
        act = self.act if any(p.requires_grad for p in self.background.parameters()) else None
        out["rgb"] = composite(out["rgb"], out["alpha"], front, back, act, image_ids)
        return out

    def render(self, cams, chunk: int | None = None, **kw: Any) -> dict:
        """Render cameras in chunks of rays -> ``rgb [C,H,W,3]``, ``alpha``, ``depth``, ``distortion [C,H,W,1]``, ``tv []``."""
        cams = cams.to(self.bounds.device)
        o, d = cams.rays()
        C, H, W = len(cams), cams.height, cams.width
        ids = cams.image_ids[:, None].expand(C, H * W).reshape(-1)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        n = chunk or self.cfg.chunk
        parts = [self._render(o[i : i + n], d[i : i + n], ids[i : i + n]) for i in range(0, o.shape[0], n)]
        out = {k: torch.cat([p[k] for p in parts]).reshape(C, H, W, -1) for k in ("rgb", "alpha", "depth", "distortion")}
        out.update(self.tv_terms())
        return out

    def tv_terms(self) -> dict[str, Tensor]:
        """``tv`` = lambda_tv TV(density) + lambda_tv_sh TV(SH) on a random subset (0 without gradients)."""
        zero = torch.zeros((), device=self.bounds.device)
        if not torch.is_grad_enabled() or not (self.density.requires_grad or self.sh.requires_grad):
            return {"tv": zero}
        c = self.cfg
        rows = random_rows(self.num_primitives(), c.tv_sparse_frac, device=self.bounds.device)
        coords, total, out = self._cached("coords"), zero, {}
        if self.density.requires_grad and c.lambda_tv > 0:
            tvd = tv_sparse(self.index, coords, self.density, rows, c.tv_eps)
            total, out["tv_density"] = total + c.lambda_tv * tvd, tvd.detach()
        if self.sh.requires_grad and c.lambda_tv_sh > 0:
            tvs = tv_sparse(self.index, coords, self.sh, rows, c.tv_eps)
            total, out["tv_sh"] = total + c.lambda_tv_sh * tvs, tvs.detach()
        out["tv"] = total
        return out

    # ------------------------------------------------------------------ optimisation
    def param_groups(self, stage: str) -> dict[str, list[nn.Parameter]]:
        """``geometry``: density and SH (and ``background`` when it learns); ``color``: SH only."""
        if stage == "geometry":
            groups = {"density": [self.density], "sh": [self.sh]}
            learned = [p for p in self.background.parameters() if p.requires_grad]
            if learned:
                groups["background"] = learned
            return groups
        if stage == "color":
            return {"sh": [self.sh]}
        raise ConfigError(f"backbone 'plenoxels': unknown stage '{stage}' (geometry|color)")

    @property
    def rays_per_step(self) -> int:
        """svox2's batch: ``batch_size`` rays per step."""
        return int(self.cfg.batch_size)

    def set_act(self, act: Any) -> None:
        """ACT is owned (and checkpointed) by the trainer, not a submodule."""
        self.__dict__["act"] = act

    def learning_rates(self, stage: str) -> dict[str, GroupSchedule]:
        """svox2's schedules: log-linear decay with a sine warm-up for ``density`` and ``sh``; ``background``
        constant."""
        c = self.cfg
        rates = {"density": GroupSchedule(c.lr_sigma, c.lr_sigma_final, c.lr_sigma_decay_steps or None, c.lr_sigma_delay_steps,
                                          c.lr_sigma_delay_mult),
                 "sh": GroupSchedule(c.lr_sh, c.lr_sh_final, c.lr_sh_decay_steps or None, c.lr_sh_delay_steps,
                                       c.lr_sh_delay_mult),
                 "background": GroupSchedule(c.lr_background)}
        return {g: rates[g] for g in self.param_groups(stage)}

    def make_optimizers(self, stage: str, groups: dict[str, list[nn.Parameter]]) -> dict[str, torch.optim.Optimizer]:
        """One RMSProp (beta ``rms_beta``) per group, over the rows each step touched (svox2); the trainer sets
        the rates every step."""
        if self.cfg.optimizer != "rmsprop":
            raise ConfigError(f"backbone 'plenoxels': optimizer '{self.cfg.optimizer}' unsupported (rmsprop)")
        return {g: SparseRMSprop([{"params": list(ps), "name": g}], lr=0.0, alpha=self.cfg.rms_beta,
                                 eps=self.cfg.rms_eps) for g, ps in groups.items()}

    def post_backward(self, step: int, out: dict, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        """Upsample (and prune) every ``upsample_every`` steps until the last resolution.

        Only while the density is being optimised (stage 1): the colour stage keeps its grid.
        """
        c = self.cfg
        if step > 0 and step % c.upsample_every == 0 and int(self.level) < len(c.reso) - 1:
            trains_density = any(p is self.density for o in optimizers.values() for g in o.param_groups
                                 for p in g["params"])
            if trains_density:
                self.upsample(optimizers)

    # ------------------------------------------------------------------ coarse to fine
    def upsample(self, optimizers: dict[str, torch.optim.Optimizer] | None = None) -> None:
        """Resample to the next resolution, prune, and point ``optimizers`` at the new parameters (state reset)."""
        c = self.cfg
        new_reso = list(c.reso[int(self.level) + 1])
        with torch.no_grad():
            index, (dens, sh) = resample(self.index.cpu(), [self.density.cpu(), self.sh.cpu()], new_reso)
        self.set_grid(index.to(self.bounds.device), dens.to(self.bounds.device), sh.to(self.bounds.device), optimizers)
        self.level.fill_(int(self.level) + 1)
        self.prune_grid(optimizers)

    def prune_grid(self, optimizers: dict | None = None) -> None:
        """Keep voxels by max training-ray weight (or density), dilated by ``prune_dilate``."""
        c = self.cfg
        if c.prune == "none" or (c.prune == "weight" and self._train_cams is None):
            return
        with torch.no_grad():
            if c.prune == "density":
                keep = torch.relu(self.density) >= c.prune_density_thresh
            else:
                keep = self.training_ray_weights() >= c.prune_weight_thresh / self.reso[2]
            if not bool(keep.any()):
                return  # nothing would survive: keep the grid as it is rather than empty it
            index, rows = prune(self.index, keep.to(self.index.device), c.prune_dilate)
            self.set_grid(index, self.density[rows], self.sh[rows], optimizers)

    def training_ray_weights(self) -> Tensor:
        """``[M]`` largest rendering weight of each stored voxel over the training views (scaled)."""
        cams = self._train_cams.to(self.bounds.device)
        budget = math.sqrt(self.cfg.prune_max_rays / max(1, len(cams) * cams.width * cams.height))
        scale = min(self.cfg.prune_image_scale, budget)
        if scale < 1.0:
            cams = cams.scaled(scale)
        fused = resolve_impl(self.cfg.rasterizer, self.bounds.device) == "cpp"
        best = torch.zeros(self.num_primitives(), dtype=self.density.dtype)
        for i in range(len(cams)):
            o, d = cams[i].rays()
            o, d = o.reshape(-1, 3), d.reshape(-1, 3)
            if fused:
                w = fused_max_weights(self.density, self.index, self._cached("coords"), self.bounds, o, d,
                                      step=self.step_world(), scale=box_scale(self.bounds), stop=self.cfg.stop_thresh)
                best = torch.maximum(best, w)
                continue
            for j in range(0, o.shape[0], self.cfg.chunk):
                out = self._render(o[j : j + self.cfg.chunk], d[j : j + self.cfg.chunk], None, return_samples=True,
                                   impl="torch")
                best = torch.maximum(best, max_weights(best.numel(), [out["samples"]]).to(best))
        return best

    def step_world(self) -> float:
        """Ray-marching step in world units: ``step_size`` times the smallest voxel side."""
        return self.cfg.step_size * float(voxel_size(self.bounds, self.reso).min())

    def set_grid(self, index: Tensor, density: Tensor, sh: Tensor, optimizers: dict | None = None) -> None:
        """Replace the grid (index ``[X,Y,Z]``, density ``[M]``, SH ``[M,K,3]``); optimisers follow, state reset."""
        old = {"density": self.density, "sh": self.sh}
        self.index = index.to(torch.int32)
        self.density = nn.Parameter(density.detach().clone().contiguous(), requires_grad=old["density"].requires_grad)
        self.sh = nn.Parameter(sh.detach().clone().contiguous(), requires_grad=old["sh"].requires_grad)
        self._cache.clear()
        mapping = {id(old["density"]): self.density, id(old["sh"]): self.sh}
        for opt in (optimizers or {}).values():
            for pg in opt.param_groups:
                for i, p in enumerate(pg["params"]):
                    if id(p) in mapping:
                        opt.state.pop(p, None)
                        pg["params"][i] = mapping[id(p)]

    # ------------------------------------------------------------------ checkpoints and export
    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Load a checkpoint saved at any resolution (the grid is resized to the saved one first)."""
        if all(k in state_dict for k in ("index", "density", "sh")):
            self.index = torch.empty_like(state_dict["index"], device=self.bounds.device)
            self.density = nn.Parameter(torch.empty_like(state_dict["density"], device=self.bounds.device),
                                        requires_grad=self.density.requires_grad)
            self.sh = nn.Parameter(torch.empty_like(state_dict["sh"], device=self.bounds.device),
                                   requires_grad=self.sh.requires_grad)
        self._cache.clear()
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def export(self, path: str) -> None:
        """Write the grid as ``.npz``: index ``[X,Y,Z]`` int32, density ``[M]``, sh ``[M,K,3]``, bounds ``[2,3]``."""
        np.savez_compressed(
            path, index=self.index.cpu().numpy(), density=self.density.detach().cpu().numpy(),
            sh=self.sh.detach().cpu().numpy(), bounds=self.bounds.cpu().numpy(), sh_degree=self.cfg.sh_degree,
        )
