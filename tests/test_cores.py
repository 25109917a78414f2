"""threads=null: the cores this process may use (CPU affinity, capped by the cgroup v2 / v1 CPU quota)."""
from __future__ import annotations

import os

import pytest
import torch

from arcsem.app import set_threads
from arcsem.cores import cgroup_cpu_limit, usable_cores


@pytest.mark.parametrize("files,expected", [
    ({"cpu.max": "max 100000\n"}, None),
    ({"cpu.max": "250000 100000\n"}, 2.5),
    ({"cpu/cpu.cfs_quota_us": "-1\n", "cpu/cpu.cfs_period_us": "100000\n"}, None),
    ({"cpu/cpu.cfs_quota_us": "100000\n", "cpu/cpu.cfs_period_us": "50000\n"}, 2.0),
    ({}, None),
    ({"cpu.max": "garbage"}, None),
])
def test_cgroup_cpu_limit(tmp_path, files, expected):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert cgroup_cpu_limit(tmp_path) == expected


def test_usable_cores_follow_affinity_and_quota(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4, 5, 6, 7})
    assert usable_cores(tmp_path) == 8  # no quota file: the affinity
    (tmp_path / "cpu.max").write_text("150000 100000")
    assert usable_cores(tmp_path) == 2  # 1.5 cores of quota: two threads
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert usable_cores(tmp_path) == 1  # pinned to one core


def test_usable_cores_follow_a_slurm_allocation(tmp_path, monkeypatch):
    """A SLURM task not bound to its cores (task/none) sees the node's 8; its allocation says 3."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4, 5, 6, 7})
    assert usable_cores(tmp_path, environ={"SLURM_CPUS_PER_TASK": "3"}) == 3
    assert usable_cores(tmp_path, environ={"SLURM_CPUS_PER_TASK": "16"}) == 8  # never more than it may use
    assert usable_cores(tmp_path, environ={"SLURM_CPUS_PER_TASK": ""}) == 8
    assert usable_cores(tmp_path, environ={}) == 8


def test_threads_null_sets_the_usable_cores(monkeypatch):
    import arcsem.cores

    before = torch.get_num_threads()
    monkeypatch.setattr(arcsem.cores, "usable_cores", lambda root="/sys/fs/cgroup": 1)
    try:
        assert set_threads(None) == 1 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_shorter_openmp_spin_respects_the_users_choice():
    from arcsem.cores import SPINCOUNT, shorter_openmp_spin

    env = {}
    assert shorter_openmp_spin(env) and env == {"GOMP_SPINCOUNT": SPINCOUNT}
    for mine in ({"GOMP_SPINCOUNT": "300000"}, {"OMP_WAIT_POLICY": "PASSIVE"}):
        env = dict(mine)
        assert not shorter_openmp_spin(env) and env == mine


def test_the_cli_sets_the_spin_before_torch_loads():
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    code = "import sys, os, arcsem.cli.main; print(os.environ['GOMP_SPINCOUNT'], 'torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    spin, torch_loaded = out.split()
    from arcsem.cores import SPINCOUNT

    assert spin == SPINCOUNT
    assert torch_loaded == "False"  # the CLI module set it before anything imported torch (libgomp reads it once)
