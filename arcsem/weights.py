"""Pretrained weights from the standard torch hub cache, shared by LPIPS and the VGG features of TCM.

Lookup order: ``$TORCH_HOME/hub/checkpoints/<file>`` (``torch.hub.get_dir()``, which honours
``TORCH_HOME`` and ``XDG_CACHE_HOME``); then a download, attempted only when the host of the URL
answers within a short timeout. When neither works the caller gets ``None`` and a reason to record
(e.g. in ``metrics.json``): a number computed with random weights must never be reported.
"""
from __future__ import annotations

import os
import socket
from pathlib import Path
from urllib.parse import urlparse

__all__ = ["FETCH_COMMAND", "KNOWN_URLS", "find_hub_weights", "hub_checkpoint_dir", "load_state_dict_from_hub", "main",
           "network_available"]

FETCH_COMMAND = "python -m arcsem.weights"
"""Downloads every known checkpoint into the hub cache (on a machine with network); printed by reports."""

# torchvision's ImageNet checkpoints (file names carry the hash prefix checked by torch.hub).
KNOWN_URLS = {
    "alexnet-owt-7be5be79.pth": "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
    "vgg16-397923af.pth": "https://download.pytorch.org/models/vgg16-397923af.pth",
    "vgg19-dcbb9e9d.pth": "https://download.pytorch.org/models/vgg19-dcbb9e9d.pth",
}
NETWORK_TIMEOUT_S = 3.0


def hub_checkpoint_dir() -> Path:
    """``$TORCH_HOME/hub/checkpoints`` (torch's default: ``~/.cache/torch/hub/checkpoints``)."""
    import torch.hub

    return Path(torch.hub.get_dir()) / "checkpoints"


def find_hub_weights(filename: str) -> Path | None:
    """Path of ``filename`` in the hub checkpoint cache, or None if it is not there (or empty)."""
    path = hub_checkpoint_dir() / Path(filename).name
    return path if path.is_file() and path.stat().st_size > 0 else None


def network_available(url: str, timeout: float = NETWORK_TIMEOUT_S) -> bool:
    """True if a TCP connection to the host of ``url`` opens within ``timeout`` seconds.

    ``ARCSEM_OFFLINE=1`` forces False (tests, air-gapped machines).
    """
    if os.environ.get("ARCSEM_OFFLINE", "") not in ("", "0"):
        return False
    parts = urlparse(url)
    port = parts.port or (443 if parts.scheme == "https" else 80)
    try:
        with socket.create_connection((parts.hostname, port), timeout=timeout):
            return True
    except OSError:
        return False


def load_state_dict_from_hub(url_or_filename: str) -> tuple[dict | None, str]:
    """Load a checkpoint from the hub cache, downloading it when a network exists.

    Args:
        url_or_filename: a full URL, or a file name (known names map to their torchvision URL).
    Returns:
        ``(state_dict, source)`` where source is the path loaded, or ``(None, reason)`` saying why
        there are no weights (``"not in <dir> and no network to fetch <url>"``, a failed download...).
    """
    import torch
    import torch.hub

    filename = Path(urlparse(url_or_filename).path).name if "://" in url_or_filename else url_or_filename
    url = url_or_filename if "://" in url_or_filename else KNOWN_URLS.get(filename)
    found = find_hub_weights(filename)
    if found is None:
        where = hub_checkpoint_dir()
        if url is None:
            return None, f"{filename} not in {where} and no known URL to download it"
        if not network_available(url):
            return None, f"{filename} not in {where} and no network to fetch {url}"
        try:
            sd = torch.hub.load_state_dict_from_url(url, map_location="cpu", progress=False, check_hash=True)
            return sd, str(where / filename)
        except Exception as exc:  # noqa: BLE001 (network flakiness, hash mismatch, ...)
            return None, f"download of {url} failed: {exc!r}"
    try:
        return torch.load(found, map_location="cpu", weights_only=True), str(found)
    except Exception as exc:  # noqa: BLE001 (any unreadable checkpoint)
        return None, f"{found} is unreadable: {exc!r}"


def main(argv: list[str] | None = None) -> int:
    """``python -m arcsem.weights [FILE...]``: put the ImageNet checkpoints (default: all of
    :data:`KNOWN_URLS`) into the torch hub cache, so LPIPS and TCM/CCM use real weights."""
    import sys

    names = list(argv if argv is not None else sys.argv[1:]) or list(KNOWN_URLS)
    failed = 0
    for name in names:
        sd, source = load_state_dict_from_hub(name)
        print(f"{name}: {'ok, ' + source if sd is not None else 'FAILED: ' + source}")
        failed += sd is None
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
