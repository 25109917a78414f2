"""The one implementation of the image metrics: PSNR, SSIM and LPIPS, each optionally inside a mask.

Images are ``[H, W, 3]`` in ``[0, 1]`` (numpy arrays or torch tensors); masks ``[H, W]`` or
``[H, W, 1]`` (bool, or > 0.5 counts as inside).

* PSNR: ``10 log10(1 / MSE)``; masked: the MSE over the mask's pixels (all three channels).
* SSIM: ``skimage.metrics.structural_similarity`` with the settings of the SSIM paper / 3DGS
  evaluations: ``gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1,
  channel_axis=-1`` (11x11 Gaussian window, K1=0.01, K2=0.03). Masked: the mean of the full SSIM map
  (``full=True``) over the mask's pixels and the channels.
* LPIPS: the ``lpips`` package, ``net='alex', version='0.1'`` (linear-layer weights ship inside the
  package). The AlexNet backbone needs the ImageNet checkpoint ``alexnet-owt-7be5be79.pth`` from the
  torch hub cache (:mod:`arcsem.weights`). Without it :func:`lpips` returns ``NaN`` and the reason,
  which callers record as ``lpips_weights: "missing: <reason>"``; a number from random weights is
  never returned. Masked: both images get a black (0) background, then the usual LPIPS.
"""
from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

__all__ = ["ALEXNET_FILE", "SSIM_SETTINGS", "image_metrics", "lpips", "lpips_model", "psnr", "ssim"]

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}
_LPIPS_CACHE: dict[str, tuple[Any, str]] = {}


def _np(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _check(pred: Any, gt: Any, mask: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    p, g = _np(pred), _np(gt)
    if p.shape != g.shape or p.ndim != 3 or p.shape[-1] != 3:
        raise ValueError(f"metrics: pred {p.shape} and gt {g.shape} must both be [H, W, 3]")
    m = None
    if mask is not None:
        m = _np(mask)
        m = (m[..., 0] if m.ndim == 3 else m) > 0.5
        if m.shape != p.shape[:2]:
            raise ValueError(f"metrics: mask {m.shape} does not match image {p.shape[:2]}")
    return p, g, m


def psnr(pred: Any, gt: Any, mask: Any = None) -> float:
    """Peak signal-to-noise ratio in dB of ``[H, W, 3]`` images in [0, 1] (inf for identical images)."""
    p, g, m = _check(pred, gt, mask)
    err = (p - g) ** 2
    mse = float(err[m].mean()) if m is not None else float(err.mean())
    if m is not None and not m.any():
        return float("nan")
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def ssim(pred: Any, gt: Any, mask: Any = None) -> float:
    """Structural similarity (scikit-image, settings in :data:`SSIM_SETTINGS`); masked: mean of the map."""
    from skimage.metrics import structural_similarity

    p, g, m = _check(pred, gt, mask)
    if m is None:
        return float(structural_similarity(p, g, channel_axis=-1, **SSIM_SETTINGS))
    if not m.any():
        return float("nan")
    _, smap = structural_similarity(p, g, channel_axis=-1, full=True, **SSIM_SETTINGS)
    return float(smap[m].mean())


def _load_alexnet_features(model: Any, state_dict: dict) -> None:
    """Copy torchvision AlexNet ``features.<i>.*`` weights into lpips' ``net.slice<k>.<i>.*`` modules."""
    import torch

    target = {}
    for k in range(1, model.net.N_slices + 1):
        for idx, module in getattr(model.net, f"slice{k}").named_children():
            for pname in dict(module.named_parameters()):
                target[f"features.{idx}.{pname}"] = (module, pname)
    missing = [k for k in target if k not in state_dict]
    if missing:
        raise KeyError(f"AlexNet checkpoint lacks {missing}")
    with torch.no_grad():
        for key, (module, pname) in target.items():
            getattr(module, pname).copy_(state_dict[key])


def lpips_model(device: str = "cpu") -> tuple[Any, str]:
    """The LPIPS(alex, v0.1) network with ImageNet AlexNet weights, or ``(None, "missing: <reason>")``.

    The second element is what ``metrics.json`` records as ``lpips_weights`` (the checkpoint path
    when found). Cached per device.
    """
    if device in _LPIPS_CACHE:
        return _LPIPS_CACHE[device]
    from .weights import load_state_dict_from_hub

    sd, source = load_state_dict_from_hub(ALEXNET_FILE)
    if sd is None:
        result: tuple[Any, str] = (None, f"missing: {source}")
    else:
        from .tvfix import import_torchvision

        import_torchvision()
        import lpips as lpips_pkg

        # pnet_rand=True: no torchvision download; the backbone is loaded from the hub cache below.
        with warnings.catch_warnings():  # torchvision's 'pretrained' deprecation notices
            warnings.simplefilter("ignore")
            model = lpips_pkg.LPIPS(pretrained=True, net="alex", version="0.1", pnet_rand=True, verbose=False)
        _load_alexnet_features(model, sd)
        result = (model.eval().to(device), source)
    _LPIPS_CACHE[device] = result
    return result


def lpips(pred: Any, gt: Any, mask: Any = None, device: str = "cpu") -> tuple[float, str]:
    """LPIPS (AlexNet, v0.1) of ``[H, W, 3]`` images in [0, 1]; returns ``(value, weights_status)``.

    ``value`` is NaN with ``weights_status = "missing: <reason>"`` when the ImageNet weights are absent.
    """
    model, status = lpips_model(device)
    if model is None:
        return float("nan"), status
    import torch

    p, g, m = _check(pred, gt, mask)
    if m is not None:
        p, g = p * m[..., None], g * m[..., None]
    to_t = lambda a: torch.from_numpy(a).float().permute(2, 0, 1)[None].to(device)
    with torch.no_grad():
        val = model(to_t(p), to_t(g), normalize=True)  # normalize: [0,1] -> [-1,1]
    return float(val.reshape(-1)[0]), status


def image_metrics(pred: Any, gt: Any, mask: Any = None, with_lpips: bool = True) -> dict[str, Any]:
    """``{"psnr", "ssim", "lpips", "lpips_weights"}`` of one view (lpips NaN when skipped or missing)."""
    out: dict[str, Any] = {"psnr": psnr(pred, gt, mask), "ssim": ssim(pred, gt, mask)}
    if with_lpips:
        out["lpips"], out["lpips_weights"] = lpips(pred, gt, mask)
    else:
        out["lpips"], out["lpips_weights"] = float("nan"), "skipped"
    return out
