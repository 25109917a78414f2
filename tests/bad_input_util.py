"""Helpers of the bad-input table (tests/test_bad_inputs*.py): tiny datasets, the console script, hashes."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
from conftest import arcsem_command, ring_poses, w2c_to_opengl_c2w, write_transforms_scene

# stage 1 in seconds: native size (no upsampling), few Gaussians, no video/LPIPS, one thread
TINY = ["train.width=null", "threads=1", "train.steps=3", "train.eval.video=false", "train.eval.lpips=false",
        "train.progress=false", "backbone.random_init_points=200",
        "colorize.steps=2", "colorize.progress=false", "colorize.eval.video=false", "colorize.eval.lpips=false",
        "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0"]


def tree_hashes(root: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file below ``root`` (inputs must come out unchanged)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def run_cli(cwd: Path, *args: str, timeout: float = 300, env: dict | None = None,
            prefix: list[str] | None = None) -> subprocess.CompletedProcess:
    """The ``arcsem`` console script with ``args`` (a debug-free environment), in ``cwd``."""
    full_env = {k: v for k, v in os.environ.items() if k not in ("ARCSEM_DEBUG", "HYDRA_FULL_ERROR")}
    full_env.update(env or {})
    return subprocess.run([*(prefix or []), *arcsem_command(), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env=full_env, check=False)


def one_error_line(proc: subprocess.CompletedProcess, code: int = 2) -> str:
    """The single ``error:`` line of a failed run: exit ``code``, no traceback, no Hydra "Error executing job"."""
    assert proc.returncode == code, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "Error executing job" not in proc.stderr, proc.stderr[-3000:]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, proc.stderr[-3000:]
    return errors[0]


def dataset(root: Path, n: int = 4, w: int = 32, h: int = 24, edit=None, **kw) -> list[str]:
    """A tiny transforms.json dataset (``edit(meta)`` may change its json); the overrides that read it."""
    path = write_transforms_scene(root, n=n, w=w, h=h, **kw)
    if edit is not None:
        meta = json.loads(path.read_text())
        edit(meta)
        path.write_text(json.dumps(meta))
    return ["dataset=transforms", f"dataset.path={path.parent}"]


def two_camera_folders(root: Path) -> Path:
    """The layout that overwrote inputs: ``json/transforms.json`` whose frames are ``../camA/img_000.png``,
    ``../camB/img_000.png`` (same file names in two folders beside the json folder), plus two unique names."""
    rng = np.random.default_rng(0)
    frames = []
    for i, (cam, stem) in enumerate([("camA", "img_000"), ("camB", "img_000"), ("camA", "img_001"),
                                     ("camB", "img_002")]):
        (root / cam).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / cam / f"{stem}.png"), rng.integers(0, 256, (24, 32), dtype=np.uint8))
        frames.append({"file_path": f"../{cam}/{stem}.png",
                       "transform_matrix": w2c_to_opengl_c2w(ring_poses(4)[i]).tolist()})
    (root / "json").mkdir(parents=True, exist_ok=True)
    meta = {"fl_x": 30.0, "fl_y": 30.0, "w": 32, "h": 24, "frames": frames}
    (root / "json" / "transforms.json").write_text(json.dumps(meta))
    colour = np.zeros((24, 32, 3), np.uint8)
    colour[..., 2] = 220  # red (BGR) reference for view img_001
    (root / "refs").mkdir(exist_ok=True)
    cv2.imwrite(str(root / "refs" / "img_001.png"), colour)
    return root


def nerf_synthetic(root: Path) -> Path:
    """``transforms_train.json`` / ``transforms_test.json`` with frames ``train/r_0`` and ``test/r_0`` (no extension)."""
    rng = np.random.default_rng(1)
    poses = ring_poses(5)
    for split, idx in (("train", [0, 1, 2]), ("test", [3, 4])):
        (root / split).mkdir(parents=True, exist_ok=True)
        frames = []
        for k, i in enumerate(idx):
            img = np.concatenate([rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
                                  np.full((24, 32, 1), 255, np.uint8)], -1)
            cv2.imwrite(str(root / split / f"r_{k}.png"), img)
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": w2c_to_opengl_c2w(poses[i]).tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.9, "frames": frames}))
    return root


def evil_checkpoint(path: Path, marker: Path) -> Path:
    """A ``torch.save`` file whose unpickling would create ``marker`` (what a crafted ``last.pt`` does)."""
    import torch

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": "arcsem-checkpoint-2", "step": 1, "payload": Evil()}, path)
    return path


def colour_reference(folder: Path, view: str = "view_01", w: int = 32, h: int = 24) -> Path:
    """A colour (red) reference image for ``view`` of a tiny dataset; returns its path."""
    colour = np.zeros((h, w, 3), np.uint8)
    colour[..., 2] = 220
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / f"{view}.png"), colour)
    return folder / f"{view}.png"
