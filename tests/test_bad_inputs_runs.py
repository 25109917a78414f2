"""The bad-input table, part 2: what happens while and after a run trains.

Outputs stay in the run folder and inputs are never written; crafted checkpoints are refused without
running their code; broken COLMAP models, a stage-1 model of another dataset, a second run in the same
folder, a read-only folder, a full disk and Ctrl-C end with one ``error:`` line; resumes are announced.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import time

import pytest
import torch
from bad_input_util import (
    TINY,
    colour_reference,
    dataset,
    evil_checkpoint,
    nerf_synthetic,
    one_error_line,
    run_cli,
    tree_hashes,
    two_camera_folders,
)
from conftest import arcsem_command, ring_poses

pytestmark = pytest.mark.slow


def test_same_file_names_in_two_folders_never_touch_the_inputs(tmp_path):
    root = two_camera_folders(tmp_path / "data")
    before = tree_hashes(root)
    run = tmp_path / "run"
    proc = run_cli(tmp_path, "stage=all", "dataset=transforms", f"dataset.path={root / 'json'}", *TINY,
                   f"colorize.references={root / 'refs' / 'img_001.png'}", f"hydra.run.dir={run}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert tree_hashes(root) == before  # no input changed, no file added beside them
    for name in ("camA/img_000", "camB/img_000", "img_001", "img_002"):
        assert (run / "renders" / "train" / f"{name}.png").is_file()
        assert (run / "colored" / f"{name}.png").is_file()
    views = (run / "views.csv").read_text()
    assert "camA/img_000" in views and "camB/img_000" in views


def test_nerf_synthetic_layout_writes_renders_and_metrics(tmp_path):
    root = nerf_synthetic(tmp_path / "lego_like")
    run = tmp_path / "run"
    proc = run_cli(tmp_path, "stage=gray", "dataset=transforms", f"dataset.path={root}", *TINY, f"hydra.run.dir={run}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["status"] == "complete" and math_finite(metrics["stage1"]["test"]["psnr"])
    # the run ends with its result and where it is (run_summary), the figures metrics.json's
    assert f"stage 1 (gs2d): held-out PSNR {metrics['stage1']['test']['psnr']:.2f} dB" in proc.stdout
    assert f"outputs: {run} (metrics.json)" in proc.stdout
    assert (run / "renders" / "test" / "test" / "r_0.png").is_file()
    assert (run / "renders" / "train" / "train" / "r_0.png").is_file()


def math_finite(x) -> bool:
    return isinstance(x, float) and math.isfinite(x)


@pytest.mark.parametrize("where", ["colorize.stage1", "run folder", "shared cache"])
def test_crafted_checkpoint_is_refused_and_never_executed(tmp_path, where):
    ds = dataset(tmp_path / "scene")
    marker = tmp_path / "PWNED"
    run, cache = tmp_path / "run", tmp_path / "cache"
    extra = [f"cache_dir={cache}", f"colorize.references={colour_reference(tmp_path / 'refs')}"]
    if where == "colorize.stage1":
        extra += ["stage=color", f"colorize.stage1={evil_checkpoint(tmp_path / 'evil.pt', marker)}"]
    elif where == "run folder":
        evil_checkpoint(run / "checkpoints" / "last.pt", marker)
        extra += ["stage=gray"]
    else:
        from test_config import compose_with

        from arcsem.share import stage1_dir

        cfg = compose_with(*ds, *TINY, *extra, "share_stage1=true")
        folder = stage1_dir(cfg)
        evil_checkpoint(folder / "checkpoints" / "last.pt", marker)
        (folder / "DONE").write_text("{}")
        extra += ["stage=color", "share_stage1=true"]
    line = one_error_line(run_cli(tmp_path, *ds, *TINY, *extra, f"hydra.run.dir={run}"))
    assert "holds Python objects other than tensors and plain data" in line, line
    assert ("evil.pt" if where == "colorize.stage1" else "last.pt") in line
    assert not marker.exists()


def test_stage1_model_of_another_dataset_is_refused(tmp_path):
    first = dataset(tmp_path / "a", seed=0)
    proc = run_cli(tmp_path, "stage=gray", *first, *TINY, f"hydra.run.dir={tmp_path / 'run_a'}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    other = dataset(tmp_path / "b", n=5, seed=1)  # other cameras, one more view
    line = one_error_line(run_cli(tmp_path, "stage=color", *other, *TINY, f"colorize.stage1={tmp_path / 'run_a'}",
                                  f"colorize.references={colour_reference(tmp_path / 'refs')}",
                                  f"hydra.run.dir={tmp_path / 'run_b'}"))
    assert "was trained on another dataset (4 training + 0 test views" in line and "(5 + 0 views" in line
    assert not (tmp_path / "run_b" / "colorize").exists()  # refused before stage 2 did anything


def test_resume_is_announced_and_the_same_run_folder_cannot_be_used_twice(tmp_path):
    ds = dataset(tmp_path / "scene")
    run = tmp_path / "run"
    args = ["stage=gray", *ds, *TINY, f"hydra.run.dir={run}"]
    assert run_cli(tmp_path, *args).returncode == 0
    again = run_cli(tmp_path, *args)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "resuming from step 3 of 3" in again.stdout + again.stderr
    assert "resuming from step 3 of 3" in (run / "main.log").read_text()
    # a long run holds the folder: a second run there stops at once and names the holder
    env = {k: v for k, v in os.environ.items() if k not in ("ARCSEM_DEBUG", "HYDRA_FULL_ERROR")}
    long = subprocess.Popen([*arcsem_command(), *args[:-1], "train.steps=100000", "train.checkpoint_every=5",
                             f"hydra.run.dir={tmp_path / 'run2'}"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(tmp_path / "run2" / "checkpoints" / "last.pt", long)
        line = one_error_line(run_cli(tmp_path, *args[:-1], f"hydra.run.dir={tmp_path / 'run2'}"))
        assert "is in use by another arcsem run" in line and f"pid {long.pid}" in line
        # Ctrl-C: the long run stops after its step, writes a checkpoint and says where
        long.send_signal(signal.SIGINT)
        _, err = long.communicate(timeout=120)
    finally:
        long.kill()
    assert long.returncode == 130, err[-2000:]
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "interrupted at step" in lines[0] and "run the same command again" in lines[0]
    state = torch.load(tmp_path / "run2" / "checkpoints" / "last.pt", weights_only=True)
    assert f"interrupted at step {state['step']} of 100000" in lines[0]
    assert json.loads((tmp_path / "run2" / "metrics.json").read_text())["status"] == "interrupted"


def _wait_for(path, proc, timeout=180):
    t0 = time.time()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        assert time.time() - t0 < timeout, f"{path} not written in {timeout} s"
        time.sleep(0.2)


def _colmap(root, broken: str):
    import cv2
    import numpy as np
    from test_readers import write_colmap

    (root / "images").mkdir(parents=True)
    for i in range(4):
        cv2.imwrite(str(root / "images" / f"view_{i:02d}.png"), np.full((24, 32), 9 * i, np.uint8))
    write_colmap(root, ring_poses(4), None, 32, 24, params=[30.0, 30.0, 16.0, 12.0], points=[([0, 0, 0], [1, 2, 3])])
    model = root / "sparse" / "0"
    if broken == "no points3D":
        (model / "points3D.bin").unlink()
    else:
        data = (model / "images.bin").read_bytes()
        (model / "images.bin").write_bytes(data[: len(data) // 2])


@pytest.mark.parametrize("broken,needle", [("no points3D", "points3D.bin missing"),
                                           ("truncated images.bin", "truncated or corrupt")])
def test_broken_colmap_model(tmp_path, broken, needle):
    _colmap(tmp_path / "scene", broken)
    before = tree_hashes(tmp_path / "scene")
    line = one_error_line(run_cli(tmp_path, "stage=check", "dataset=colmap", f"dataset.path={tmp_path / 'scene'}",
                                  f"hydra.run.dir={tmp_path / 'run'}"))
    assert needle in line and "sparse/0" in line
    assert tree_hashes(tmp_path / "scene") == before


def _private_mount() -> list[str] | None:
    """``unshare`` into a private user+mount namespace (so a test can mount a tiny or read-only file system
    without root and without touching the machine), or None where the kernel does not allow it."""
    if shutil.which("unshare") is None:
        return None
    ok = subprocess.run(["unshare", "-rm", "true"], capture_output=True, check=False).returncode == 0
    return ["unshare", "-rm"] if ok else None


def test_read_only_folder_and_full_disk(tmp_path):
    prefix = _private_mount()
    if prefix is None:
        pytest.skip("no private mount namespace here (unshare -rm): cannot make a real read-only or full disk")
    ds = dataset(tmp_path / "scene")
    ro, small = tmp_path / "ro", tmp_path / "small"
    ro.mkdir()
    small.mkdir()
    cmd = " ".join(arcsem_command())
    script = (f"mount --bind {ro} {ro} && mount -o remount,ro,bind {ro} && "
              f"mount -t tmpfs -o size=160k tmpfs {small} && "
              f"{{ {cmd} stage=gray {' '.join(ds + TINY)} hydra.run.dir={ro}/run; echo rc=$? >&2; "
              f"{cmd} stage=gray {' '.join(ds + TINY)} train.checkpoint_every=1 hydra.run.dir={small}/run; "
              "echo rc=$? >&2; }")
    proc = subprocess.run([*prefix, "sh", "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                          check=False)
    blocks = proc.stderr.split("rc=")
    assert len(blocks) == 3, proc.stderr[-3000:]
    read_only, full = blocks[0], blocks[1].split("\n", 1)[1]
    assert blocks[1].startswith("2") and blocks[2].startswith("2"), proc.stderr[-3000:]
    for text in (read_only, full):
        assert "Traceback" not in text and len([ln for ln in text.splitlines() if ln.startswith("error:")]) == 1
    assert "read-only" in read_only and f"{ro}/run" in read_only
    assert "No space left on device" in full or "no space left" in full, full[-2000:]
