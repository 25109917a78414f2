"""ACT: a per-image affine colour transform (Darmon et al. 2024, as used by ArCSEM).

Each training image ``i`` has a transform ``L' = W_i * L + b_i`` applied to every primitive's (or
sample's) decoded colour BEFORE compositing, then clamped to ``[0, 1]``; a pixel therefore gets
``W C + b alpha``. It absorbs the per-image brightness/contrast drift of SEM images so the scene
itself stays consistent. Novel views (``image_id == -1``) use the mean ``W`` and ``b`` over training
images.

Two parameterisations (``conf/act/*.yaml``):

* ``mode="rgb"``   — 3 weights + 3 biases per image: the paper's text (lr 1e-4, ``act=paper``);
* ``mode="scalar"`` — 1 scale + 1 shift per image broadcast over RGB: the authors' released code
  (lr 1e-3, ``act=code``).

Initialisation: identity plus ``N(0, init_noise)`` noise on both ``W`` and ``b``.

Solvers (``act.solver``): ``adam`` (the paper, the default: ``W, b`` are trained by the trainer as
group ``act``) or ``closed_form`` (an experiment): after each step the batch's transforms move by
``fit_rate`` towards the least-squares fit of the observed images to the render before ACT, with an
optional ridge ``fit_prior`` towards the identity (:meth:`ACT.fit_views`); Adam never touches them.
On the built-in scene every faster ACT loses held-out PSNR, the closed form most: per-view transforms
and the scene's view-dependent SH colour can trade brightness freely, and the mean transform used
for novel views does not undo the trade (benchmarks/results/README.md, "What ACT learns").
``smooth_degree = L >= 0`` removes that trade: the transforms as applied (:meth:`ACT.effective`) lose
their part that is a polynomial of degree <= L in the training views' directions (what SH colours of
degree L can hold; :func:`smooth_projector`), keeping their mean; the parameters themselves are free.
ACT is independent of any backbone: Gaussians call :meth:`ACT.apply` on ``[C, N, 3]`` colours,
ray backbones on ``[R, S, 3]`` per-sample colours with ``[R]`` image ids.
"""
from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor, nn

from .configs import ACT_MODES, ACT_SOLVERS

__all__ = ["ACT", "ACT_MODES", "ACT_SOLVERS", "affine_fit", "smooth_projector"]


class ACT(nn.Module):
    """Per-image affine colour transforms.

    Attributes:
        weight: ``[num_images, k]`` with ``k = 3`` (rgb) or ``1`` (scalar).
        bias: ``[num_images, k]``.
    """

    def __init__(self, num_images: int, mode: Literal["rgb", "scalar"] = "rgb", init_noise: float = 1e-3,
                 solver: Literal["adam", "closed_form"] = "adam", fit_rate: float = 0.5, fit_prior: float = 0.0,
                 view_dirs: Tensor | None = None, smooth_degree: int = -1):
        super().__init__()
        if mode not in ACT_MODES:
            raise ValueError(f"ACT mode must be one of {ACT_MODES}, got '{mode}'")
        if solver not in ACT_SOLVERS:
            raise ValueError(f"act.solver must be one of {ACT_SOLVERS}, got '{solver}'")
        if not 0.0 < fit_rate <= 1.0:
            raise ValueError(f"act.fit_rate must be in (0, 1], got {fit_rate}")
        if fit_prior < 0:
            raise ValueError(f"act.fit_prior must be >= 0, got {fit_prior}")
        self.solver, self.fit_rate, self.fit_prior = solver, float(fit_rate), float(fit_prior)
        if num_images < 1:
            raise ValueError(f"ACT needs at least one training image, got {num_images}")
        k = 3 if mode == "rgb" else 1
        self.mode = mode
        if smooth_degree >= 0:
            if view_dirs is None or view_dirs.shape != (num_images, 3):
                raise ValueError(f"act.smooth_degree={smooth_degree} needs the {num_images} training views' "
                                 f"directions [N, 3], got {None if view_dirs is None else tuple(view_dirs.shape)}")
            self.register_buffer("smooth", smooth_projector(view_dirs, smooth_degree))
        grad = solver == "adam"
        self.weight = nn.Parameter(torch.ones(num_images, k) + init_noise * torch.randn(num_images, k), grad)
        self.bias = nn.Parameter(init_noise * torch.randn(num_images, k), grad)

    @property
    def num_images(self) -> int:
        return self.weight.shape[0]

    def transforms(self, image_ids: Tensor) -> tuple[Tensor, Tensor]:
        """``W, b`` of shape ``[*image_ids.shape, k]``; id ``-1`` gives the mean over training images."""
        ids = image_ids.long().to(self.weight.device)
        if (ids >= self.num_images).any() or (ids < -1).any():
            raise IndexError(f"ACT: image ids {ids.unique().tolist()} outside -1..{self.num_images - 1}")
        novel = (ids < 0)[..., None]
        safe = ids.clamp_min(0)
        W_all, b_all = self.effective()
        W = torch.where(novel, W_all.mean(0), W_all[safe])
        b = torch.where(novel, b_all.mean(0), b_all[safe])
        return W, b

    def effective(self) -> tuple[Tensor, Tensor]:
        """Every training image's ``W, b`` (``[N, k]``) as applied: the parameters, minus their smooth
        part across view directions when ``smooth_degree >= 0`` (the mean is kept)."""
        if not hasattr(self, "smooth"):
            return self.weight, self.bias
        P = self.smooth.to(self.weight.dtype)
        return self.weight - P @ self.weight, self.bias - P @ self.bias

    def apply(self, colors: Tensor, image_ids: Tensor) -> Tensor:
        """Transform colours of the images ``image_ids``.

        Args:
            colors: ``[*B, ..., 3]`` decoded colours, e.g. ``[C, N, 3]`` (one row of primitives per
                camera) or ``[R, S, 3]`` (samples of a ray batch).
            image_ids: ``[*B]`` long, training-image index per leading entry; ``-1`` = novel view.
        Returns:
            ``clamp(W * colors + b, 0, 1)`` with the shape of ``colors``.
        """
        ids = torch.as_tensor(image_ids)
        nb = ids.ndim
        if tuple(colors.shape[:nb]) != tuple(ids.shape) or colors.shape[-1] != 3:
            raise ValueError(f"ACT.apply: colors {tuple(colors.shape)} do not start with image_ids {tuple(ids.shape)}"
                             " or do not end with 3 channels")
        W, b = self.transforms(ids)
        extra = colors.ndim - nb - 1
        shape = (*ids.shape, *([1] * extra), W.shape[-1])
        out = W.reshape(shape).to(colors.dtype) * colors + b.reshape(shape).to(colors.dtype)
        return out.clamp(0.0, 1.0)

    forward = apply

    @torch.no_grad()
    def fit_views(self, rgb: Tensor, alpha: Tensor, target: Tensor, image_ids: Tensor) -> None:
        """Closed-form step: move the views' ``W, b`` by ``fit_rate`` towards :func:`affine_fit`.

        Args:
            rgb: ``[C, H, W, 3]`` renders made WITH the current transforms of ``image_ids``.
            alpha: ``[C, H, W, 1]`` their opacities.
            target: ``[C, H, W, 3]`` the observed images.
            image_ids: ``[C]`` training-image indices (no ``-1``).
        The render before ACT is recovered as ``(rgb - b alpha) / W`` (exact where no splat colour was
        clamped).
        """
        ids = torch.as_tensor(image_ids).long().to(self.weight.device)
        if (ids < 0).any():
            raise ValueError("ACT.fit_views: novel views (id -1) have no transform to fit")
        W, b = self.transforms(ids)
        shape = (len(ids), 1, 1, W.shape[-1])
        W4, b4 = W.reshape(shape).to(rgb.dtype), b.reshape(shape).to(rgb.dtype)
        pre = (rgb - b4 * alpha) / W4
        W_fit, b_fit = affine_fit(pre, alpha, target, self.mode, self.fit_prior)
        r = self.fit_rate
        for j, i in enumerate(ids.tolist()):  # rows one by one: a view may appear twice in a batch
            self.weight[i] += r * (W_fit[j].to(self.weight.dtype) - self.weight[i])
            self.bias[i] += r * (b_fit[j].to(self.bias.dtype) - self.bias[i])

    def extra_repr(self) -> str:
        return f"num_images={self.num_images}, mode={self.mode}"


def affine_fit(pre: Tensor, alpha: Tensor, target: Tensor, mode: str, prior: float = 0.0) -> tuple[Tensor, Tensor]:
    """Least-squares ``W, b`` (``[C, k]``) with ``target ~ W * pre + b * alpha`` per view.

    Args:
        pre: ``[C, H, W, 3]`` render before ACT; alpha ``[C, H, W, 1]``; target ``[C, H, W, 3]``.
        mode: ``"rgb"`` (one fit per channel, k = 3) or ``"scalar"`` (channels pooled, k = 1).
        prior: ridge weight per fitted value towards the identity: ``+ prior * n * ((W - 1)^2 + b^2)``
            for ``n`` values in the fit (1: about half-way between the fit and the identity).
    A view with no contrast in ``pre`` (singular system) keeps ``W = 1, b = 0``.
    """
    x, a, y = pre.double(), alpha.double().expand_as(pre), target.double()
    dims = (1, 2) if mode == "rgb" else (1, 2, 3)
    n = prior * float(x[0].numel() if mode != "rgb" else x[0, ..., 0].numel())
    sxx, sxa, saa = (x * x).sum(dims) + n, (x * a).sum(dims), (a * a).sum(dims) + n
    sxy, say = (x * y).sum(dims) + n, (a * y).sum(dims)
    det = sxx * saa - sxa * sxa
    ok = det > 1e-9 * (sxx * saa).clamp_min(1e-30)
    safe = torch.where(ok, det, torch.ones_like(det))
    W = torch.where(ok, (sxy * saa - sxa * say) / safe, torch.ones_like(det))
    b = torch.where(ok, (sxx * say - sxa * sxy) / safe, torch.zeros_like(det))
    if mode != "rgb":
        W, b = W[:, None], b[:, None]
    return W, b


def smooth_projector(view_dirs: Tensor, degree: int) -> Tensor:
    """``[N, N]`` projector onto the smooth functions of the view direction, minus the constant.

    The span of the monomials ``x^a y^b z^c`` (``a + b + c <= degree``) of the unit directions
    ``view_dirs [N, 3]`` (= real SH up to ``degree`` on the sphere), with the constant removed, so that
    ``W - P @ W`` keeps ``W``'s mean and loses exactly what SH colours of that degree could also express.
    """
    d = torch.nn.functional.normalize(view_dirs.double(), dim=-1)
    cols = [d[:, 0] ** a * d[:, 1] ** b * d[:, 2] ** c
            for a in range(degree + 1) for b in range(degree + 1 - a) for c in range(degree + 1 - a - b)]
    M = torch.stack(cols, 1)
    M = M - M.mean(0, keepdim=True)  # orthogonal to the constant: the mean is left alone
    U, S, _ = torch.linalg.svd(M, full_matrices=False)
    U = U[:, S > 1e-8 * max(float(S.max()), 1e-30)] if S.numel() else U[:, :0]
    return U @ U.T
