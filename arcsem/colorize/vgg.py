"""VGG feature extractor for TCM/CCM: VGG16 (default, Ref-NPR) or VGG19 (ArCSEM code), torchvision's layers.

Features are the relu3_x and relu4_x layers, concatenated along channels per block (VGG16: 3 x 256
channels at 1/4 resolution and 3 x 512 at 1/8; VGG19: 4 x 256 and 4 x 512). Inputs are normalised
with the ImageNet mean/std. Weights come from the torch hub cache (:mod:`arcsem.weights`); where
they cannot be had the network runs with RANDOM weights after a loud warning (one per job, in its log), and
``features_source`` says ``"random"`` so that runs record ``vgg16-random`` (:meth:`VGGFeatures.label`). The random
weights are drawn from a fixed seed (:data:`RANDOM_SEED`): the same in every run and process.
"""
from __future__ import annotations

import logging

import torch
from torch import Tensor, nn

__all__ = ["IMAGENET_MEAN", "IMAGENET_STD", "VGG_CFG", "WEIGHT_FILES", "VGGFeatures", "block_layers", "get_vgg",
           "vgg_layers"]

log = logging.getLogger(__name__)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
WEIGHT_FILES = {"vgg16": "vgg16-397923af.pth", "vgg19": "vgg19-dcbb9e9d.pth"}
# The convolution trunks of Simonyan & Zisserman's configurations D (VGG16) and E (VGG19): output channels of each
# 3x3 convolution (padding 1, then a ReLU), "M" a 2x2 max pool of stride 2; the layer order of torchvision's
# ``vgg.features``, so its ImageNet checkpoints load by index (``features.<i>.weight``).
VGG_CFG = {"vgg16": (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"),
           "vgg19": (64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512, "M",
                     512, 512, 512, 512, "M")}


RANDOM_SEED = 0
"""The seed of the trunk's initial weights, which a run keeps where no ImageNet weights are found: the same random
extractor in every run and process, as a pretrained one is. (Drawn from the global random state, as before, the
features of a Hydra multirun job depended on which job had built the per-process extractor first.)"""


def vgg_layers(arch: str) -> nn.Sequential:
    """``vgg.features`` of ``arch`` (``vgg16``/``vgg19``), built here rather than by torchvision (whose import costs
    seconds a process): the same modules in the same order, so also the same default-initialised random weights."""
    layers: list[nn.Module] = []
    channels = 3
    for v in VGG_CFG[arch]:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(channels, int(v), kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            channels = int(v)
    return nn.Sequential(*layers)


def block_layers(features: nn.Sequential, blocks=(3, 4)) -> dict[int, list[int]]:
    """Indices of the ReLU layers of each block in torchvision's ``vgg.features`` (block b = after b-1 pools)."""
    out: dict[int, list[int]] = {b: [] for b in blocks}
    block = 1
    for i, layer in enumerate(features):
        if isinstance(layer, nn.MaxPool2d):
            block += 1
        elif isinstance(layer, nn.ReLU) and block in out:
            out[block].append(i)
    return out


class VGGFeatures(nn.Module):
    """Frozen VGG trunk; ``forward(images [C, H, W, 3] in [0, 1]) -> [block features [C, D_b, h_b, w_b]]``.

    Attributes:
        arch: ``"vgg16"`` or ``"vgg19"``. blocks: VGG blocks used (default relu3_x, relu4_x).
        features_source: ``"imagenet"`` or ``"random"``; weights_detail: path loaded or why not.
    """

    def __init__(self, arch: str = "vgg16", blocks=(3, 4), load_weights: bool = True):
        super().__init__()
        from ..errors import ConfigError

        if arch not in WEIGHT_FILES:
            raise ConfigError(f"vgg: unknown architecture '{arch}'; use vgg16 or vgg19")
        net = nn.Module()
        with torch.random.fork_rng(devices=[]):  # the global random state is left as it was
            torch.manual_seed(RANDOM_SEED)
            net.features = vgg_layers(arch)  # features only: the classifier is never used
        self.arch, self.blocks = arch, tuple(blocks)
        self.name, self.strides = arch, tuple(2 ** (b - 1) for b in self.blocks)  # block b: after b-1 pools
        self.features_source, self.weights_detail = "random", "not requested"
        self.layers = block_layers(net.features, self.blocks)
        last = max(i for ids in self.layers.values() for i in ids)
        self.trunk = net.features[: last + 1]
        if load_weights:
            self._load()
        else:
            self._warn_random("weights not requested")
        # ReLUs in place would overwrite the activations we keep
        for m in self.trunk:
            if isinstance(m, nn.ReLU):
                m.inplace = False
        self.trunk.requires_grad_(False).eval()
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def _load(self) -> None:
        from ..weights import load_state_dict_from_hub

        sd, detail = load_state_dict_from_hub(WEIGHT_FILES[self.arch])
        if sd is None:
            self._warn_random(detail)
            return
        own = {k[len("features."):]: t for k, t in sd.items() if k.startswith("features.")}
        wanted = self.trunk.state_dict()
        bad = [k for k, t in wanted.items() if k not in own or own[k].shape != t.shape]
        if bad:
            self._warn_random(f"{detail} lacks or mis-shapes features.{bad[0]}")
            return
        self.trunk.load_state_dict({k: own[k] for k in wanted})
        self.features_source, self.weights_detail = "imagenet", detail

    def _warn_random(self, why: str) -> None:
        """One warning (the job's log: console and main.log), naming what ``metrics.json`` records."""
        msg = (f"VGG ({self.arch}) runs with RANDOM weights ({why}); TCM/CCM matches are not the paper's. "
               f"Put {WEIGHT_FILES[self.arch]} into the torch hub cache; this run records "
               f"'features: {self.label()}' in metrics.json.")
        self.weights_detail = why
        log.warning(msg)

    differentiable = True  # usable on a colour render: the paper's TCM loss space

    def key(self) -> str:
        """Cache identity: architecture, blocks and a hash of the weights."""
        if getattr(self, "_key", None) is None:
            from .pseudocolor import cache_key

            weights = cache_key(*[t for _, t in sorted(self.trunk.state_dict().items())])
            self._key = f"vgg:{self.arch}:{self.blocks}:{self.features_source}:{weights}"
        return self._key

    def label(self) -> str:
        """``vgg16-imagenet`` or ``vgg16-random`` (what runs record as ``features``)."""
        return f"{self.arch}-{self.features_source}"

    def train(self, mode: bool = True):  # the trunk always stays in eval mode
        super().train(mode)
        self.trunk.eval()
        return self

    def forward(self, images: Tensor) -> list[Tensor]:
        # NCHW in memory, as the weights are: a render permuted to [C, 3, H, W] is channels-last in memory, and
        # oneDNN's convolutions ran 1.6x slower forward and backward on it (a layout mismatch; benchmarks/vgg_layout.py)
        x = (images.permute(0, 3, 1, 2) if images.shape[-1] == 3 else images).contiguous()
        x = (x - self.mean) / self.std
        keep = {i: b for b, ids in self.layers.items() for i in ids}
        acts: dict[int, list[Tensor]] = {b: [] for b in self.blocks}
        for i, layer in enumerate(self.trunk):
            x = layer(x)
            if i in keep:
                acts[keep[i]].append(x)
        return [torch.cat(acts[b], 1) for b in self.blocks]


_CACHE: dict[tuple, VGGFeatures] = {}


def get_vgg(arch: str = "vgg16", blocks=(3, 4)) -> VGGFeatures:
    """A shared extractor per (arch, blocks): weights are looked up (and warned about) once per process."""
    key = (arch, tuple(blocks))
    if key not in _CACHE:
        _CACHE[key] = VGGFeatures(arch, blocks)
    return _CACHE[key]
