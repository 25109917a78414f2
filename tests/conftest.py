"""Generic fixtures shared by the test files: a writer of tiny transforms.json datasets."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

# `make test` runs two xdist workers on a 2-core machine: one torch thread each avoids spinning
# worker threads competing for the same cores (measured 2-4x faster under load).
if "PYTEST_XDIST_WORKER" in __import__("os").environ:
    torch.set_num_threads(1)


@pytest.fixture
def one_thread():
    """One torch thread for the test (tiny tensors: oversubscribed threads on the shared 2-core
    machine made the trainer tests 20x slower); restores the previous count."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def ring_poses(n: int, radius: float = 4.0) -> np.ndarray:
    """``[n, 4, 4]`` world->camera (OpenCV axes) on an arc around the origin, looking at it."""
    from arcsem.cameras import look_at

    ang = torch.linspace(-0.6, 0.6, n, dtype=torch.float64)
    eye = torch.stack([radius * torch.sin(ang), 0.3 * torch.cos(3 * ang), -radius * torch.cos(ang)], -1)
    return look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)).numpy()


def w2c_to_opengl_c2w(w2c: np.ndarray) -> np.ndarray:
    """World->camera (OpenCV) ``[4, 4]`` -> camera->world in OpenGL axes (transforms.json convention)."""
    return np.linalg.inv(w2c) @ np.diag([1.0, -1.0, -1.0, 1.0])


def write_transforms_scene(root: Path, n: int = 4, w: int = 16, h: int = 12, fl: float = 20.0,
                           model: str | None = None, ext: str = ".png", bits: int = 8, seed: int = 0,
                           frame_extra=None, **top) -> Path:
    """Write ``n`` random grey images and a ``transforms.json``; returns the json path.

    ``frame_extra(i, frame)`` may edit each frame dict; ``top`` adds top-level keys.
    """
    import cv2

    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    frames = []
    for i, w2c in enumerate(ring_poses(n)):
        dtype, vmax = (np.uint8, 255) if bits == 8 else (np.uint16, 65535)
        img = rng.integers(0, vmax + 1, size=(h, w), dtype=dtype)
        cv2.imwrite(str(root / f"view_{i:02d}{ext}"), img)
        frame = {"file_path": f"view_{i:02d}{ext}", "transform_matrix": w2c_to_opengl_c2w(w2c).tolist()}
        if frame_extra is not None:
            frame_extra(i, frame)
        frames.append(frame)
    meta = {"fl_x": fl, "fl_y": fl * 1.1, "cx": w / 2 + 0.25, "cy": h / 2 - 0.5, "w": w, "h": h, **top}
    if model is not None:
        meta["camera_model"] = model
    meta["frames"] = frames
    path = root / "transforms.json"
    path.write_text(json.dumps(meta, indent=1))
    return path


@pytest.fixture
def tiny_transforms(tmp_path):
    """Factory: ``tiny_transforms(**kw) -> transforms.json path`` (see :func:`write_transforms_scene`)."""

    def make(sub: str = "scene", **kw) -> Path:
        return write_transforms_scene(tmp_path / sub, **kw)

    return make


# ------------------------------------------------------------------ console scripts
CONF = Path(__file__).resolve().parent.parent / "conf"


def arcsem_command() -> list[str]:
    exe = Path(sys.executable).with_name("arcsem")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "arcsem.cli.main"]


def missing_defaults(overrides=()) -> list[str]:
    """``~group`` for defaults of conf/config.yaml whose file does not exist (yet) and that the
    overrides do not choose."""
    chosen = {o.split("=")[0] for o in overrides if "=" in o}
    out = []
    for entry in yaml.safe_load((CONF / "config.yaml").read_text())["defaults"]:
        if isinstance(entry, dict):
            (group, option), = entry.items()
            if group.startswith("optional ") or "${" in str(option):  # optional: a missing file is fine
                continue
            if option is not None and group not in chosen and not (CONF / group / f"{option}.yaml").is_file():
                out.append(f"~{group}")
    return out
