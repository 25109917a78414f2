"""``GaussianBackbone``: what 2DGS and 3DGS share (parameters, SH colours, ACT, densification, PLY).

Subclasses set ``num_scales`` (2 surfels / 3 ellipsoids), ``random_rotations`` and ``_rasterize``
(the pure render function). Defaults are those of the official 3DGS/2DGS repositories (30k-step
schedule); see docs/method.md.

Step convention: ``post_backward(step, ...)`` is called after the backward pass of step ``step``
(0-based) and prepares step ``step + 1`` (SH degree, position learning rate, densification), like the
official loop with its 1-based ``iteration = step + 1``.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from arcsem.cameras import Cameras
from arcsem.configs import GroupSchedule
from arcsem.plugins import Backbone, RenderOutput
from arcsem.timing import region

from .config import GaussianConfig
from .densify import DensifyStats, clone_split_prune, reset_opacity, screen_grad_norms
from .init import init_gaussians, random_points
from .model import GaussianModel, active_sh_degree_at
from .ply import read_ply, write_ply

__all__ = ["GaussianBackbone", "GaussianConfig"]

GEOMETRY_GROUPS = {"xyz": "means", "f_dc": "sh_dc", "f_rest": "sh_rest", "opacity": "opacity_logits",
                   "scaling": "log_scales", "rotation": "quats"}
COLOR_GROUPS = ("f_dc", "f_rest")


class GaussianBackbone(Backbone):
    """Gaussians with SH colours, an optional ACT, and official-style densification."""

    Config: ClassVar[type] = GaussianConfig
    num_scales: ClassVar[int] = 3
    random_rotations: ClassVar[bool] = False

    def __init__(self, cfg: GaussianConfig, scene: Any = None, act: nn.Module | None = None, **runtime: Any):
        super().__init__(cfg, scene)
        self.model = GaussianModel(self._initial_params(scene), cfg.sh_degree)
        extent = float(scene.extent) if scene is not None else 1.0
        self.register_buffer("extent", torch.tensor(extent, dtype=torch.float64))
        self.extent_value = extent  # host copy of the buffer (read without waiting for a device)
        self._background: Tensor | None = None  # cfg.background on the model's device, made once
        self.act = act  # ACT or None; its parameters are optimised by the trainer (group "act")
        self.stage = "geometry"
        self.stats = DensifyStats.zeros(len(self.model))
        self._last_cams: Cameras | None = None

    def _initial_params(self, scene: Any) -> dict[str, Tensor]:
        cfg = self.cfg
        points = getattr(scene, "points", None)
        colors = getattr(scene, "point_colors", None)
        if points is None or len(points) == 0:
            bounds = scene.bounds if scene is not None else torch.tensor([[-1.0] * 3, [1.0] * 3])
            points, colors = random_points(bounds, cfg.random_init_points), None
        return init_gaussians(points, colors, num_scales=self.num_scales, sh_degree=cfg.sh_degree,
                              opacity=cfg.init_opacity, random_rotations=self.random_rotations)

    # ------------------------------------------------------------------ run checks (arcsem.plugins.Backbone)
    @classmethod
    def check_config(cls, cfg: GaussianConfig, device: str) -> None:
        """``rasterizer=gsplat`` (the optional CUDA rasteriser) needs gsplat and a CUDA ``device``; ``triton``: 2-D
        splats, triton and a CUDA ``device``."""
        if cfg.rasterizer == "gsplat":
            from .gsplat_bridge import require_gsplat

            require_gsplat(device)
        if cfg.rasterizer == "triton":
            cls._require_triton(device)

    @classmethod
    def _require_triton(cls, device) -> None:
        from arcsem.errors import ConfigError
        from arcsem.tritonsupport import available

        if cls.num_scales != 2:
            raise ConfigError("backbone.rasterizer=triton composites 2-D splats only (backbone=gs2d); use auto")
        why = available(device)
        if why is not None:
            raise ConfigError(f"backbone.rasterizer=triton {why}")

    @classmethod
    def check_scene(cls, cfg: GaussianConfig, scene: Any) -> None:
        """``rasterizer=gsplat``: every camera of the scene must be one gsplat draws (its 2DGS: pinhole only)."""
        if cfg.rasterizer != "gsplat":
            return
        from .gsplat_bridge import gsplat_cameras

        for split in (scene.train, scene.test):
            if len(split):
                gsplat_cameras(split.cameras, two_d=cls.num_scales == 2)

    # ------------------------------------------------------------------ rendering
    def _rasterize(self, means, quats, scales, opacities, colors, cams, **kw) -> RenderOutput:
        raise NotImplementedError

    def render(self, cams: Cameras, background: Tensor | None = None, **kw: Any) -> RenderOutput:
        """Render ``C`` cameras: SH colours per view (+ ACT by ``cams.image_ids``), then rasterise.

        Returns the renderer's dict: ``rgb [C,H,W,3]``, ``alpha``, ``depth`` ... plus ``radii [C,N]`` and
        ``visible [C,N]`` (used for densification statistics).
        """
        m = self.model
        cams = cams.to(device=m.means.device, dtype=m.means.dtype)
        impl = self._impl(m.means.device)
        with region("arcsem::render/sh"):  # SH colours and ACT; profiler regions: benchmarks/profile_step.py
            colors = m.colors(cams, impl=_sh_impl(impl), act=self.act)  # [C, N, 3]
        if background is None:
            background = self._default_background(m.means)
        means, quats, scales, opacities = self.splat_params()
        out = self._rasterize(means, quats, scales, opacities, colors, cams, background=background,
                              tile=self.cfg.tile, chunk_tiles=self.cfg.chunk_tiles, impl=impl)
        if torch.is_grad_enabled():
            self._last_cams = cams  # the cameras whose gradient post_backward reads
        return out

    def colour_operator(self, cams: Cameras):
        """A render of ``cams`` for as long as the geometry stays as it is now (stage 2): the compositing weights
        recorded once (the fused kernels, or the PyTorch path on any device), then each call a sparse product of the
        SH colours (:mod:`.frozen`); None where the rasteriser is gsplat's or an ACT is set."""
        m = self.model
        cams = cams.to(device=m.means.device, dtype=m.means.dtype)
        impl = self._impl(m.means.device)
        if impl not in ("cpp", "torch", "triton") or self.act is not None:
            return None
        from .frozen import FrozenColours, FrozenRender

        bg = self._default_background(m.means)
        with torch.no_grad():
            means, quats, scales, opacities = self.splat_params()
            sh = _sh_impl(impl)
            out = self._rasterize(means, quats, scales, opacities, m.colors(cams, impl=sh), cams, background=bg,
                                  tile=self.cfg.tile, chunk_tiles=self.cfg.chunk_tiles, impl=impl, colour_weights=True)
        weights = out.pop("colour_weights")
        colours = FrozenColours(weights, tuple(out["rgb"].shape[:3]), bg)
        return FrozenRender(out, colours, lambda: m.colors(cams, impl=sh))

    def _default_background(self, like: Tensor) -> Tensor:
        """``cfg.background`` ``[3]`` on ``like``'s device and dtype, made on the first render there (not each step:
        a tensor from Python values is a transfer to the device)."""
        bg = self._background
        if bg is None or bg.device != like.device or bg.dtype != like.dtype:
            bg = self._background = torch.tensor(self.cfg.background, dtype=like.dtype).to(like.device)
        return bg

    def _impl(self, device) -> str:
        """The ``rasterizer`` choice resolved for ``device``: ``cpp`` (fused kernels: SH colours and the rasteriser),
        ``torch``, ``gsplat`` (gsplat's CUDA rasteriser, PyTorch SH colours) or ``triton`` (the PyTorch path with
        Triton projection, footprints and compositing; ``auto``'s choice for 2DGS on CUDA where Triton imports); a
        ConfigError where the choice cannot run."""
        from .fused import resolve_impl

        if self.cfg.rasterizer == "gsplat":
            from .gsplat_bridge import require_gsplat

            require_gsplat(device)
            return "gsplat"
        if self.cfg.rasterizer == "triton":
            self._require_triton(device)
            return "triton"
        if self.cfg.rasterizer == "auto" and self.num_scales == 2:
            from arcsem.tritonsupport import auto_on

            if auto_on(device):  # 2DGS on CUDA with Triton (benchmarks/results/gpu/README.md)
                return "triton"
        return resolve_impl(self.cfg.rasterizer, str(device))

    def splat_params(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """What the rasteriser draws: means ``[N, 3]``, quaternions ``[N, 4]``, scales ``[N, S]``, opacities ``[N]``
        (differentiable functions of the model's parameters). A Gaussian variant overrides this to filter them
        (e.g. Mip-Splatting's 3-D smoothing filter, examples/mip_splatting); default: the model's own."""
        m = self.model
        return m.means, m.quats, m.scales, m.opacities

    # ------------------------------------------------------------------ optimisation
    def param_groups(self, stage: str) -> dict[str, list[nn.Parameter]]:
        """``"geometry"``: all six groups (official names); ``"color"``: ``f_dc`` and ``f_rest`` only.

        Selecting a stage also sets ``requires_grad`` (the colour stage freezes geometry) and the
        stage used by :meth:`post_backward` (no densification in the colour stage). ACT is not
        included: the trainer adds it as its own group.
        """
        if stage not in ("geometry", "color"):
            raise ValueError(f"unknown stage '{stage}'; expected 'geometry' or 'color'")
        self.stage = stage
        names = GEOMETRY_GROUPS if stage == "geometry" else COLOR_GROUPS
        for group, attr in GEOMETRY_GROUPS.items():
            getattr(self.model, attr).requires_grad_(group in names)
        return {g: [getattr(self.model, GEOMETRY_GROUPS[g])] for g in names}

    def learning_rates(self, stage: str) -> dict[str, GroupSchedule]:
        """The official rates of the groups of ``stage``; position: log-linear from init to final x extent over
        ``lr_position_max_steps``, the others constant."""
        c, ext = self.cfg, self.extent_value
        rates = {"xyz": GroupSchedule(c.lr_position_init * ext, c.lr_position_final * ext, c.lr_position_max_steps),
                 "f_dc": GroupSchedule(c.lr_feature), "f_rest": GroupSchedule(c.lr_feature_rest),
                 "opacity": GroupSchedule(c.lr_opacity), "scaling": GroupSchedule(c.lr_scaling),
                 "rotation": GroupSchedule(c.lr_rotation)}
        return {g: rates[g] for g in self.param_groups(stage)}

    def pre_backward(self, step: int, out: RenderOutput) -> None:
        """Nothing to do: the densification statistic is read from the 3-D means' gradient."""

    def post_backward(self, step: int, out: RenderOutput, optimizers) -> None:
        """Stage 1 only: SH degree, densification statistics, densify/prune/reset.

        Learning rates are the trainer's (:func:`arcsem.train.optim.apply_schedules` follows
        :meth:`learning_rates` unless ``train.optim.groups`` overrides a group).

        Runs after the backward pass of 0-based ``step`` and before the optimiser step; changed
        parameters lose their ``.grad`` for this step (as the official new Parameters do).
        """
        if self.stage != "geometry":
            return
        c, it = self.cfg, step + 1  # official 1-based iteration
        self.model.set_active_sh_degree(active_sh_degree_at(it, c.sh_degree, c.sh_increase_every))
        if not c.densify or it >= c.densify_until:
            return
        with torch.no_grad():
            with region("arcsem::densify/stats"):
                self._accumulate(out)
            with region("arcsem::densify/passes"):
                if it > c.densify_from and it % c.densify_every == 0:
                    self.densify_and_prune(optimizers, screen=it > c.opacity_reset_every)
                if it % c.opacity_reset_every == 0:
                    reset_opacity(self.model, optimizers)

    def _accumulate(self, out: RenderOutput) -> None:
        grad, cams = self.model.means.grad, self._last_cams
        if grad is None or cams is None or "radii" not in out:
            return
        radii = out["radii"]
        visible = out.get("visible", radii > 0)
        if visible.shape[1] != len(self.stats):  # the model changed since this render
            return
        fusable = self.stats.grad_sum.device == grad.device and self.stats.grad_sum.dtype == torch.float32
        impl = self._impl(grad.device) if fusable else "torch"
        if impl in ("cpp", "triton"):  # the same, in one fused pass (C++) or one kernel launch (Triton)
            if impl == "cpp":
                from .fused import densify_stats
            else:
                from ._triton_densify import densify_stats_triton as densify_stats

            densify_stats(self.stats, grad, self.model.means, cams, visible, radii)
        else:
            self.stats.accumulate(screen_grad_norms(grad, self.model.means, cams), visible, radii)

    def densify_and_prune(self, optimizers, screen: bool = True) -> dict[str, int]:
        """One clone/split/prune pass with the accumulated statistics; resets them."""
        c = self.cfg
        info = clone_split_prune(
            self.model, self.stats, optimizers, grad_threshold=c.densify_grad_threshold,
            percent_dense=c.percent_dense, extent=self.extent_value, min_opacity=c.prune_opacity,
            max_screen_size=c.max_screen_size if screen else None, max_world_scale=c.max_world_scale,
        )
        self.stats = DensifyStats.zeros(len(self.model), device=self.model.means.device)
        return info

    # ------------------------------------------------------------------ persistence
    def num_primitives(self) -> int:
        return len(self.model)

    def export(self, path: str) -> None:
        """Write a PLY that common 3DGS viewers read (2DGS: two scales, see ply.py)."""
        write_ply(path, self.model.params())

    def export_viewer(self, folder: str, cams: Cameras, names: list[str], centre: Tensor,
                      iteration: int) -> dict[str, str]:
        """The INRIA folder layout with the mean ACT baked into the colours (see inria.py)."""
        from .inria import write_viewer_folder

        return write_viewer_folder(folder, self.model.params(), cams, names, centre, iteration, self.act)

    def load_ply(self, path: str) -> None:
        """Replace the Gaussians by those of a PLY written by :meth:`export` or the official code."""
        params = read_ply(path)
        if params["log_scales"].shape[1] != self.num_scales:
            raise ValueError(f"{path}: {params['log_scales'].shape[1]} scales, {self.name} needs {self.num_scales}")
        self.model.set_params(params)
        self.model.set_active_sh_degree(min(self.cfg.sh_degree, math.isqrt(params["sh_rest"].shape[1] + 1) - 1))
        self.stats = DensifyStats.zeros(len(self.model), device=self.model.means.device)

    def get_extra_state(self) -> dict[str, Tensor]:
        """The densification statistics ride in ``state_dict()`` (key ``_extra_state``), so a run
        resumed between two densification passes continues exactly where it stopped."""
        return {"grad_sum": self.stats.grad_sum, "count": self.stats.count, "max_radii": self.stats.max_radii}

    def set_extra_state(self, state: dict[str, Tensor]) -> None:
        dev = self.model.means.device
        self.stats = DensifyStats(*(state[k].detach().clone().to(dev) for k in ("grad_sum", "count", "max_radii")))

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Load a checkpoint with any number of Gaussians (parameters are resized); ACT entries are
        ignored when this backbone has no ACT (e.g. the colour stage). Checkpoints without
        densification statistics (older files, exported models) start them at zero."""
        sd = dict(state_dict)
        if self.act is None:
            sd = {k: v for k, v in sd.items() if not k.startswith("act.")}
        sd.setdefault("_extra_state", None)
        if sd["_extra_state"] is None:
            n = len(sd.get("model.means", self.model.means))
            sd["_extra_state"] = DensifyStats.zeros(n).__dict__
        result = super().load_state_dict(sd, strict=strict, assign=assign)
        self.extent_value = float(self.extent)
        if len(self.stats) != len(self.model):  # the model was edited outside densification: start afresh
            self.stats = DensifyStats.zeros(len(self.model), device=self.model.means.device)
        return result


def _sh_impl(impl: str) -> str:
    """The SH colours' path for the rasteriser's ``impl``: the fused C++ kernel with ``cpp``, the Triton kernels with
    ``triton``, else PyTorch's (gsplat's rasteriser takes PyTorch colours)."""
    return impl if impl in ("cpp", "triton") else "torch"
