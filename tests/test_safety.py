"""Unit tests of the safety parts: view names, the write guard, locks, checkpoints, per-stage metrics."""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from arcsem.errors import OutputError, TrainingError
from arcsem.guard import out_path, protect
from arcsem.names import view_names


@pytest.mark.parametrize("files,names", [
    (["/d/json/../camA/img_000.png", "/d/camB/img_000.png", "/d/x/r 1.png"], ["camA/img_000", "camB/img_000", "r_1"]),
    (["/d/train/r_0.png", "/d/test/r_0.png", "/d/train/r_1.png"], ["train/r_0", "test/r_0", "r_1"]),
    (["/d/a.png", "/d/a.tif", "/e/a_2.png"], ["a", "a_2", "a_2_2"]),  # same stem, same folder: numbered
    (["/d/.hidden.png", "/x/...png"], ["hidden", "view"]),  # no hidden files, no '..'
])
def test_view_names_are_unique_relative_and_safe(files, names):
    out = view_names(files)
    assert out == names
    assert all(not n.startswith("/") and ".." not in n.split("/") for n in out)


def test_out_path_refuses_escaping_names(tmp_path):
    assert out_path(tmp_path, "camA/img_000", ".png") == tmp_path / "camA" / "img_000.png"
    assert (tmp_path / "camA").is_dir()
    for bad in ("/etc/passwd", "../x", "a/../../x", ""):
        with pytest.raises(OutputError, match="unsafe output name"):
            out_path(tmp_path, bad, ".png")


def test_guard_refuses_writes_to_inputs_and_outside(tmp_path):
    run, data, elsewhere = tmp_path / "run", tmp_path / "data", tmp_path / "elsewhere"
    for d in (run, data, elsewhere):
        d.mkdir()
    (data / "img.png").write_bytes(b"input")
    with protect([run], inputs=[data / "img.png"], input_dirs=[data]):
        (run / "ok.txt").write_text("fine")  # the run folder
        with pytest.raises(OutputError, match="it is an input file"):
            (data / "img.png").write_bytes(b"overwritten")
        with pytest.raises(OutputError, match="input folder"):
            (data / "new.png").write_bytes(b"x")
        with pytest.raises(OutputError, match="outside the run folder"):
            np.save(elsewhere / "t.npy", np.zeros(3))
        with pytest.raises(OutputError, match="outside the run folder"):
            (elsewhere / "sub").mkdir()
        with pytest.raises(OutputError, match="it is an input file"):
            os.replace(run / "ok.txt", data / "img.png")
        assert (data / "img.png").read_bytes() == b"input"  # reading inputs is fine
    (elsewhere / "after.txt").write_text("the guard is off outside protect()")
    assert sorted(p.name for p in data.iterdir()) == ["img.png"]


def test_waiting_lock_announces_the_wait(tmp_path, caplog):
    from filelock import FileLock

    from arcsem.locks import LOCK_NAME, run_folder_lock, waiting_lock

    def hold(path, seconds, started):  # another job (a thread here) holds the lock for a while
        with FileLock(str(path / LOCK_NAME)):
            started.set()
            time.sleep(seconds)

    started = threading.Event()
    threading.Thread(target=hold, args=(tmp_path, 1.0, started)).start()
    started.wait()
    t0 = time.perf_counter()
    with caplog.at_level(logging.INFO, logger="arcsem.locks"), waiting_lock(tmp_path, "the shared model"):
        waited = time.perf_counter() - t0
    assert waited >= 0.5
    assert any("waiting for the shared model" in r.getMessage() for r in caplog.records)
    assert any("acquired after" in r.getMessage() for r in caplog.records)
    (tmp_path / "run").mkdir()
    started = threading.Event()
    holder = threading.Thread(target=hold, args=(tmp_path / "run", 1.0, started))
    holder.start()
    started.wait()
    with pytest.raises(OutputError, match="is in use by another arcsem run"), run_folder_lock(tmp_path / "run"):
        pass  # refused at once, no wait
    holder.join()


def test_checkpoint_without_format_is_refused(tmp_path):
    from arcsem.train.checkpoint import load_checkpoint, save_checkpoint

    torch.save({"step": 3, "model": {}}, tmp_path / "old.pt")  # plain data, but not written by arcsem
    with pytest.raises(TrainingError, match="not an arcsem checkpoint of format"):
        load_checkpoint(tmp_path / "old.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(TrainingError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path / "junk.pt")
    save_checkpoint(tmp_path / "ok.pt", {"step": 1, "x": torch.ones(2)})
    assert load_checkpoint(tmp_path / "ok.pt")["step"] == 1
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left


def test_metrics_are_written_after_each_stage(tmp_path, monkeypatch):
    """A failure in stage 2 keeps stage 1's results in metrics.json, with the failed stage and its error."""
    import cv2
    import numpy as np
    from conftest import write_transforms_scene
    from test_config import compose_with

    import arcsem.colorize
    import arcsem.train
    from arcsem import app
    from arcsem.errors import DataError

    scene = write_transforms_scene(tmp_path / "scene", n=3)
    cv2.imwrite(str(tmp_path / "view_01.png"), np.full((12, 16, 3), (0, 0, 200), np.uint8))

    def stage2(cfg, sc, run_dir):
        raise DataError("something only stage 2 could find out")

    monkeypatch.setattr(arcsem.train, "run_stage1", lambda cfg, sc, run_dir: {"stage1": {"psnr": 30.5}})
    monkeypatch.setattr(arcsem.colorize, "run_stage2", stage2)
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=all",
                       f"colorize.references={tmp_path / 'view_01.png'}", "colorize.losses.tcm.weight=0",
                       "colorize.losses.ccm.weight=0")  # 16x12 images: too small for TCM/CCM (the preflight says)
    with pytest.raises(DataError):
        app.run(cfg, run_dir=tmp_path / "r")
    saved = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert saved["stage1"] == {"psnr": 30.5} and saved["completed_stages"] == ["gray"]
    assert saved["status"] == "failed" and saved["failed_stage"] == "color"
    assert saved["error"] == "something only stage 2 could find out"


@pytest.mark.parametrize("env", [{"TORCH_HOME": "hub_elsewhere"}, {"XDG_CACHE_HOME": "xdg"},
                                 {"TORCH_HOME": "hub_elsewhere", "TORCH_EXTENSIONS_DIR": "ext"}])
def test_the_kernels_build_folder_is_allowed_wherever_torch_puts_it(tmp_path, monkeypatch, env):
    """The fused kernels build under PyTorch's extension folder ($TORCH_EXTENSIONS_DIR, else torch_extensions in
    the user cache, not under $TORCH_HOME): with TORCH_HOME set elsewhere (to keep hub weights there) the guard
    refused that folder and every run fell back to the PyTorch path."""
    from arcsem.cext import build_dir
    from arcsem.guard import allowed_roots, inside

    for k in ("TORCH_HOME", "XDG_CACHE_HOME", "TORCH_EXTENSIONS_DIR"):
        monkeypatch.delenv(k, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, str(tmp_path / v))
    where = build_dir("arcsem_fused_raster_0123456789ab")
    assert any(inside(where, root) for root in allowed_roots(tmp_path / "run"))
    if "TORCH_EXTENSIONS_DIR" in env:
        assert inside(where, tmp_path / "ext")


@pytest.mark.parametrize("env", [{}, {"TRITON_HOME": "th"}, {"TRITON_CACHE_DIR": "tc"}])
def test_tritons_kernel_cache_is_allowed_wherever_triton_puts_it(tmp_path, monkeypatch, env):
    """``rasterizer=triton`` compiles its kernels into Triton's cache on first use: the guard refused
    ``~/.triton/cache`` and the first GPU run stopped before its first step. The folder as Triton itself
    computes it (``triton.knobs.cache.dir``) is allowed, with and without Triton's variables."""
    knobs = pytest.importorskip("triton.knobs")
    from arcsem.guard import allowed_roots, inside

    for k in ("TRITON_HOME", "TRITON_CACHE_DIR"):
        monkeypatch.delenv(k, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, str(tmp_path / v))
    where = Path(knobs.cache.dir) / "XU5DT2AO5BD5AEHEYGLPP5LRDFHHCUEJT4LGDVLB4STXUGVGHFPA" / "kernel.cubin"
    assert any(inside(where, root) for root in allowed_roots(tmp_path / "run")), where
    if env:
        assert inside(where, tmp_path / next(iter(env.values())))
