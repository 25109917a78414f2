"""Dense DAISY descriptors (Tola et al. 2010; OpenCV contrib ``cv2.xfeatures2d.DAISY_create``) for TCM/CCM.

DAISY was designed for dense wide-baseline matching: at every sample point, histograms of gradient
orientations (``q_theta`` bins) on rings of Gaussian-smoothed orientation maps (``q_radius`` rings of
``q_hist`` histograms within ``radius`` pixels), 200 numbers with the defaults. It needs no learned
weights. Descriptors are sampled at the centres of the TCM blocks' cells (stride 4 and 8, as VGG's
relu3_x and relu4_x), with a radius that grows with the stride (15 and 30 px by default, about the
half receptive field of those VGG blocks), each histogram normalised (``NRM_PARTIAL``), so the
exposure drift of SEM images cancels.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = ["DaisyFeatures", "cell_centres"]


def cell_centres(h: int, w: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates ``x [w // s]``, ``y [h // s]`` of the ``stride``-pixel cells of an ``h x w`` image."""
    off = (stride - 1) / 2.0
    return np.arange(w // stride) * stride + off, np.arange(h // stride) * stride + off


def require_daisy() -> None:
    """PluginError unless the installed OpenCV has DAISY (``cv2.xfeatures2d``, OpenCV contrib)."""
    import cv2

    if not hasattr(cv2, "xfeatures2d"):
        from ...errors import PluginError

        raise PluginError("colorize.features=daisy needs OpenCV contrib (opencv-contrib-python-headless); "
                          "the installed cv2 has no xfeatures2d")


class DaisyFeatures:
    """``images [N, H, W, 3]`` -> per block ``[N, 200, H // s, W // s]`` dense DAISY (float32, no gradient)."""

    name = "daisy"
    differentiable = False

    def __init__(self, strides: tuple[int, ...] = (4, 8), radii: tuple[float, ...] = (15.0, 30.0),
                 q_radius: int = 3, q_theta: int = 8, q_hist: int = 8):
        self.strides, self.radii = tuple(strides), tuple(radii)
        self.q = (q_radius, q_theta, q_hist)

    def key(self) -> str:
        import cv2

        return f"daisy-v1:{self.strides}:{self.radii}:{self.q}:opencv-{cv2.__version__}"

    def label(self) -> str:
        return "daisy"

    def _descriptor(self, radius: float):
        import cv2

        require_daisy()
        q_radius, q_theta, q_hist = self.q
        return cv2.xfeatures2d.DAISY_create(radius=float(radius), q_radius=q_radius, q_theta=q_theta,
                                            q_hist=q_hist, norm=cv2.xfeatures2d.DAISY_NRM_PARTIAL)

    def _one(self, grey: np.ndarray, desc, stride: int) -> np.ndarray:
        """``[D, h // s, w // s]`` DAISY of one uint8 ``[h, w]`` image at the cell centres of ``stride``."""
        import cv2

        h, w = grey.shape
        xs, ys = cell_centres(h, w, stride)
        kps = [cv2.KeyPoint(float(x), float(y), 1.0) for y in ys for x in xs]
        kept, d = desc.compute(grey, kps)
        if d is None or len(kept) != len(kps):
            raise RuntimeError(f"DAISY returned {0 if d is None else len(kept)} of {len(kps)} descriptors")
        return d.reshape(len(ys), len(xs), -1).transpose(2, 0, 1)

    def __call__(self, images: Tensor) -> list[Tensor]:
        grey = (images.detach().float().mean(-1).clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()
        descs = [self._descriptor(r) for r in self.radii]
        out = []
        for s, desc in zip(self.strides, descs):
            out.append(torch.from_numpy(np.stack([self._one(g, desc, s) for g in grey])).float())
        return out
