"""arcsem.share: content-addressed stage-1 folders and the lock that makes parallel jobs train once."""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from arcsem.share import (
    cache_root,
    ensure_stage1,
    is_done,
    stage1_dir,
    stage1_key,
    stage1_lock,
    stage1_result,
)

BASE = {"dataset": {"name": "synthetic", "resolution": 64}, "backbone": {"name": "gs2d"},
        "act": {"enabled": True, "mode": "rgb"}, "train": {"steps": 100}, "seed": 0,
        "colorize": {"references": "five"}, "stage": "all", "device": "cpu"}


def _cfg(**changes):
    cfg = OmegaConf.create(BASE)
    for key, value in changes.items():
        OmegaConf.update(cfg, key, value)
    return cfg


def test_key_depends_on_stage1_config_only():
    k = stage1_key(_cfg())
    assert len(k) == 16 and all(c in "0123456789abcdef" for c in k)
    # stage-2 settings, device and stage do not change the stage-1 model
    assert stage1_key(_cfg(**{"colorize.references": "one", "stage": "gray", "device": "cuda"})) == k
    assert stage1_key(dict(reversed(list(BASE.items())))) == k  # order of keys irrelevant; plain dicts too
    assert stage1_key(_cfg(**{"train.progress": False, "train.log_every": 7})) == k  # bookkeeping only
    for change in ({"seed": 1}, {"act.enabled": False}, {"backbone.name": "gs3d"}, {"train.steps": 101},
                   {"dataset.resolution": 32}):
        assert stage1_key(_cfg(**change)) != k, change


def test_key_of_the_builtin_scene_follows_its_generator_version(monkeypatch):
    """A regenerated built-in scene (new GENERATOR_VERSION) must not reuse models of the old one."""
    from arcsem.synthetic import write

    synthetic, other = _cfg(**{"dataset.kind": "synthetic"}), _cfg(**{"dataset.kind": "transforms"})
    before = stage1_key(synthetic), stage1_key(other)
    monkeypatch.setattr(write, "GENERATOR_VERSION", write.GENERATOR_VERSION + 1)
    assert stage1_key(synthetic) != before[0]
    assert stage1_key(other) == before[1]


def test_key_follows_the_source_code(monkeypatch, tmp_path):
    """A model trained by other code (an edit, another commit with the same version) is not reused."""
    from arcsem import share

    k = stage1_key(_cfg())
    monkeypatch.setattr(share, "source_digest", lambda: "0" * 16)
    assert stage1_key(_cfg()) != k
    # the digest: every source file by path and content; other files do not count
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "sub" / "k.cpp").write_text("int f();\n")
    d = share.tree_digest([tmp_path / "pkg"])
    (tmp_path / "pkg" / "README.md").write_text("notes")
    assert share.tree_digest([tmp_path / "pkg"]) == d
    (tmp_path / "pkg" / "sub" / "k.cpp").write_text("int f(int);\n")
    assert share.tree_digest([tmp_path / "pkg"]) != d
    (tmp_path / "pkg" / "sub" / "k.cpp").write_text("int f();\n")
    (tmp_path / "pkg" / "sub" / "k.cpp").rename(tmp_path / "pkg" / "k.cpp")  # same content, moved
    assert share.tree_digest([tmp_path / "pkg"]) != d
    assert len(share.source_digest()) == 16
    roots = share.source_roots()  # the core and both plugin folders, wherever they are installed
    assert len({r.resolve() for r in roots}) == 3 and all((r / "__init__.py").is_file() for r in roots)
    assert any((r / "gaussians" / "cpp").is_dir() for r in roots)  # the backbones' C++ sources count


def test_dir_root_and_description(tmp_path, monkeypatch):
    monkeypatch.setenv("ARCSEM_CACHE", str(tmp_path / "env"))
    assert cache_root(_cfg()) == tmp_path / "env"
    path = stage1_dir(_cfg())
    assert path == tmp_path / "env" / "stage1" / stage1_key(_cfg()) and path.is_dir()
    assert '"seed": 0' in (path / "key.json").read_text()
    cfg = _cfg(cache_dir=str(tmp_path / "cfg"))  # cfg.cache_dir wins over the environment
    assert stage1_dir(cfg).parent.parent == tmp_path / "cfg"
    monkeypatch.delenv("ARCSEM_CACHE")
    assert cache_root({}) == Path("~/.cache/arcsem").expanduser()


def _worker(root: str, log: str, barrier) -> None:
    cfg = _cfg(cache_dir=root)

    def train(path: Path) -> None:
        with open(log, "a") as fh:
            fh.write(f"train {os.getpid()} {time.monotonic()}\n")
        time.sleep(1.0)  # long enough that the other process is surely waiting on the lock
        (path / "model.pt").write_text(str(os.getpid()))
        with open(log, "a") as fh:
            fh.write(f"done {os.getpid()} {time.monotonic()}\n")
        return {"stage1": {"trained_by": os.getpid()}}

    barrier.wait()
    path, trained = ensure_stage1(cfg, train)
    with open(log, "a") as fh:
        fh.write(f"{'trained' if trained else 'reused'} {os.getpid()} {time.monotonic()} "
                 f"{(path / 'model.pt').read_text()} {stage1_result(path)['stage1']['trained_by']}\n")


def test_two_processes_train_once(tmp_path):
    ctx = mp.get_context("fork")
    barrier = ctx.Barrier(2)
    log = tmp_path / "log.txt"
    procs = [ctx.Process(target=_worker, args=(str(tmp_path), str(log), barrier)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    lines = [ln.split() for ln in log.read_text().splitlines()]
    kinds = [ln[0] for ln in lines]
    assert kinds.count("train") == 1 and kinds.count("trained") == 1 and kinds.count("reused") == 1
    trainer = next(ln for ln in lines if ln[0] == "train")[1]
    done_t = float(next(ln for ln in lines if ln[0] == "done")[2])
    reused = next(ln for ln in lines if ln[0] == "reused")
    # the waiting process got the model the other one trained, after training had finished
    assert reused[1] != trainer and reused[3] == trainer and float(reused[2]) >= done_t
    assert reused[4] == trainer  # the trainer's returned metrics reach the job that reused the model
    assert is_done(stage1_dir(_cfg(cache_dir=str(tmp_path))))


def test_failed_training_is_retried(tmp_path):
    cfg = _cfg(cache_dir=str(tmp_path))

    def boom(path):
        raise RuntimeError("diverged")

    with pytest.raises(RuntimeError):
        ensure_stage1(cfg, boom)
    assert not is_done(stage1_dir(cfg))
    calls = []
    path, trained = ensure_stage1(cfg, calls.append)
    assert trained and calls == [path] and is_done(path)
    assert stage1_result(path) is None  # train_fn returned no dict
    assert ensure_stage1(cfg, calls.append) == (path, False) and len(calls) == 1


def test_lock_is_exclusive(tmp_path):
    import fcntl

    # while held, a second open file description cannot take it
    with stage1_lock(tmp_path / "x") as path, open(path / ".arcsem.lock") as fh, pytest.raises(BlockingIOError):
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    with open(tmp_path / "x" / ".arcsem.lock") as fh:  # released after the block
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
