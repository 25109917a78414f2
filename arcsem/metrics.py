"""The one implementation of the image metrics: PSNR, SSIM and LPIPS, each optionally inside a mask.

Images are ``[H, W, 3]`` in ``[0, 1]`` (numpy arrays or torch tensors); masks ``[H, W]`` or
``[H, W, 1]`` (bool, or > 0.5 counts as inside).

Two conventions (:data:`CONVENTIONS`, ``train.eval.metrics`` / ``colorize.eval.metrics``):

* ``3dgs`` (the default): what the evaluation scripts of 3DGS and 2DGS compute, which the ArCSEM paper used.
  Their ``render.py`` saves renders as 8-bit PNG and ``metrics.py`` scores the files, so the render is
  quantised to 8 bits first (``round(255 x) / 255``); SSIM is their ``ssim()``: an 11x11 Gaussian window
  (sigma 1.5) applied with zero padding ("same" size), ``C1 = 0.01^2``, ``C2 = 0.03^2``, the mean of the map
  over every pixel and channel (:func:`arcsem.imageops.ssim_map`, the function the ``dssim`` loss uses);
  LPIPS with the VGG network (``lpips(..., net_type='vgg')``).
* ``skimage``: the float render; SSIM by ``skimage.metrics.structural_similarity`` with
  ``gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1`` (reflecting borders, the
  outer 5 pixels left out of the mean); LPIPS with AlexNet (the ``lpips`` package's default).

* PSNR: ``10 log10(1 / MSE)``; masked: the MSE over the mask's pixels (all three channels).
* SSIM masked: the mean of the full map over the mask's pixels and the channels.
* LPIPS: the ``lpips`` package, v0.1 (its linear-layer weights ship inside the package). The network
  (AlexNet or VGG16) needs its ImageNet checkpoint (``alexnet-owt-7be5be79.pth`` / ``vgg16-397923af.pth``)
  from the torch hub cache (:mod:`arcsem.weights`). Without it :func:`lpips` returns ``NaN`` and the
  reason, which callers record as ``lpips_weights: "missing: <reason>"``; a number from random weights is
  never returned. Masked: both images get a black (0) background, then the usual LPIPS.
"""
from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

__all__ = ["ALEXNET_FILE", "CONVENTIONS", "LPIPS_FILES", "SSIM_SETTINGS", "image_metrics", "lpips", "lpips_model",
           "metric_convention", "psnr", "quantise", "ssim"]

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
LPIPS_FILES = {"alex": ALEXNET_FILE, "vgg": "vgg16-397923af.pth"}
CONVENTIONS = {"3dgs": {"quantise": True, "ssim": "3dgs", "lpips_net": "vgg"},
               "skimage": {"quantise": False, "ssim": "skimage", "lpips_net": "alex"}}
"""What each metric convention does (see the module docstring); recorded in ``metrics.json``."""


def metric_convention(name: str) -> dict[str, Any]:
    """What ``metrics.json`` records of a convention: ``{"name", "quantise", "ssim", "lpips_net"}``."""
    if name not in CONVENTIONS:
        raise ValueError(f"metrics convention must be one of {', '.join(CONVENTIONS)}, got {name!r}")
    return {"name": name, **CONVENTIONS[name]}


SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}
_LPIPS_CACHE: dict[tuple[str, str], tuple[Any, str]] = {}


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


def quantise(img: Any) -> np.ndarray:
    """``[H, W, 3]`` in [0, 1] as an 8-bit file would hold it: ``round(255 x) / 255`` (float64)."""
    return np.round(np.clip(_np(img), 0.0, 1.0) * 255.0) / 255.0


def ssim(pred: Any, gt: Any, mask: Any = None, convention: str = "3dgs") -> float:
    """Structural similarity under ``convention`` (module docstring); masked: the mean of the map inside."""
    p, g, m = _check(pred, gt, mask)
    if m is not None and not m.any():
        return float("nan")
    if convention == "3dgs":
        import torch

        from .imageops import ssim_map

        smap = ssim_map(torch.from_numpy(p)[None], torch.from_numpy(g)[None])[0].numpy()
        return float(smap[m].mean()) if m is not None else float(smap.mean())
    if convention != "skimage":
        raise ValueError(f"ssim: convention must be one of {', '.join(CONVENTIONS)}, got {convention!r}")
    from skimage.metrics import structural_similarity

    if m is None:
        return float(structural_similarity(p, g, channel_axis=-1, **SSIM_SETTINGS))
    _, smap = structural_similarity(p, g, channel_axis=-1, full=True, **SSIM_SETTINGS)
    return float(smap[m].mean())


def _load_features(model: Any, state_dict: dict) -> None:
    """Copy torchvision AlexNet / VGG16 ``features.<i>.*`` weights into lpips' ``net.slice<k>.<i>.*`` modules."""
    import torch

    target = {}
    for k in range(1, model.net.N_slices + 1):
        for idx, module in getattr(model.net, f"slice{k}").named_children():
            for pname in dict(module.named_parameters()):
                target[f"features.{idx}.{pname}"] = (module, pname)
    missing = [k for k in target if k not in state_dict]
    if missing:
        raise KeyError(f"ImageNet checkpoint lacks {missing}")
    with torch.no_grad():
        for key, (module, pname) in target.items():
            getattr(module, pname).copy_(state_dict[key])


def lpips_model(device: str = "cpu", net: str = "alex") -> tuple[Any, str]:
    """The LPIPS(``net``, v0.1) network with ImageNet weights, or ``(None, "missing: <reason>")``.

    ``net``: ``alex`` or ``vgg``. The second element is what ``metrics.json`` records as ``lpips_weights``
    (the checkpoint path when found). Cached per device and network.
    """
    if net not in LPIPS_FILES:
        raise ValueError(f"lpips: net must be one of {', '.join(LPIPS_FILES)}, got {net!r}")
    if (device, net) in _LPIPS_CACHE:
        return _LPIPS_CACHE[(device, net)]
    from .weights import load_state_dict_from_hub

    sd, source = load_state_dict_from_hub(LPIPS_FILES[net])
    if sd is None:
        result: tuple[Any, str] = (None, f"missing: {source}")
    else:
        from .tvfix import import_torchvision

        import_torchvision()
        import lpips as lpips_pkg

        # pnet_rand=True: no torchvision download; the backbone is loaded from the hub cache below.
        with warnings.catch_warnings():  # torchvision's 'pretrained' deprecation notices
            warnings.simplefilter("ignore")
            model = lpips_pkg.LPIPS(pretrained=True, net=net, version="0.1", pnet_rand=True, verbose=False)
        _load_features(model, sd)
        result = (model.eval().to(device), source)
    _LPIPS_CACHE[(device, net)] = result
    return result


def lpips(pred: Any, gt: Any, mask: Any = None, device: str = "cpu", net: str = "alex") -> tuple[float, str]:
    """LPIPS (``net``: alex or vgg, v0.1) of ``[H, W, 3]`` images in [0, 1]; returns ``(value, weights_status)``.

    ``value`` is NaN with ``weights_status = "missing: <reason>"`` when the ImageNet weights are absent.
    """
    model, status = lpips_model(device, net)
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


def image_metrics(pred: Any, gt: Any, mask: Any = None, with_lpips: bool = True,
                  convention: str = "3dgs") -> dict[str, Any]:
    """``{"psnr", "ssim", "lpips", "lpips_weights"}`` of one view under ``convention`` (:data:`CONVENTIONS`);
    lpips NaN when skipped or its weights are missing."""
    if convention not in CONVENTIONS:
        raise ValueError(f"metrics convention must be one of {', '.join(CONVENTIONS)}, got {convention!r}")
    conv = CONVENTIONS[convention]
    pred = quantise(pred) if conv["quantise"] else pred
    out: dict[str, Any] = {"psnr": psnr(pred, gt, mask), "ssim": ssim(pred, gt, mask, conv["ssim"])}
    if with_lpips:
        out["lpips"], out["lpips_weights"] = lpips(pred, gt, mask, net=conv["lpips_net"])
    else:
        out["lpips"], out["lpips_weights"] = float("nan"), "skipped"
    return out
