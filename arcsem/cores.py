"""How many cores this process may use: what ``threads=null`` means.

``os.cpu_count()`` (and torch's default thread count) counts the machine's cores, not this process's: a
cluster job pinned to 4 cores of a 64-core node (CPU affinity, ``taskset``, Slurm's ``--cpus-per-task``) or
limited by a container's CPU quota (cgroup v2 ``cpu.max``, v1 ``cpu.cfs_quota_us``) that starts 64 threads
spin-waits them against each other and runs several times slower than with 4. A SLURM job on a cluster that
does not bind tasks to cores (``TaskPlugin=task/none``) sees the whole node: its allocation,
``SLURM_CPUS_PER_TASK``, caps the count too.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

__all__ = ["SPINCOUNT", "cgroup_cpu_limit", "shorter_openmp_spin", "slurm_allocation", "usable_cores"]

SPINCOUNT = "3000"


def cgroup_cpu_limit(root: str | os.PathLike = "/sys/fs/cgroup") -> float | None:
    """The CPU quota of this process's cgroup in cores (``quota / period``), or None when unlimited or unknown.

    Reads cgroup v2 ``<root>/cpu.max`` (``"max 100000"`` or ``"200000 100000"``), else cgroup v1
    ``<root>/cpu/cpu.cfs_quota_us`` and ``cpu.cfs_period_us`` (quota -1: unlimited).
    """
    root = Path(root)
    try:
        quota, period = (root / "cpu.max").read_text().split()[:2]
        return None if quota == "max" else float(quota) / float(period)
    except (OSError, ValueError):
        pass
    try:
        quota = float((root / "cpu" / "cpu.cfs_quota_us").read_text())
        period = float((root / "cpu" / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return None if quota <= 0 or period <= 0 else quota / period


def slurm_allocation(environ=os.environ) -> int | None:
    """The cores SLURM gave this job's task (``SLURM_CPUS_PER_TASK``), or None outside a job or when unset."""
    value = environ.get("SLURM_CPUS_PER_TASK", "")
    return int(value) if value.isdigit() and int(value) > 0 else None


def usable_cores(root: str | os.PathLike = "/sys/fs/cgroup", environ=os.environ) -> int:
    """Cores this process may run on: its CPU affinity, capped by the cgroup quota (rounded up) and by a SLURM
    job's allocation (:func:`slurm_allocation`); at least 1."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        n = os.cpu_count() or 1
    limit = cgroup_cpu_limit(root)
    if limit is not None:
        n = min(n, max(1, math.ceil(limit)))
    slurm = slurm_allocation(environ)
    if slurm is not None:
        n = min(n, slurm)
    return max(1, n)


def shorter_openmp_spin(environ=os.environ) -> bool:
    """Set ``GOMP_SPINCOUNT`` to :data:`SPINCOUNT` unless the user chose a wait policy or spin count; True if set.

    PyTorch's CPU operations run on GNU OpenMP, whose threads spin about 300,000 iterations at every barrier
    before they sleep. On a machine shared with other processes they burn the cores those processes need:
    beside one busy process a 2DGS + ACT step took 4.3x its idle time. With 3,000 (f09ae5e, two threads): idle
    3 % faster than with 1,000 and beside one busy process 1.62x the idle time (1,000: 1.58x; 10,000: as fast
    idle as 3,000 but 1.75x); ``OMP_WAIT_POLICY=PASSIVE``: 1.6x but 11 % slower idle (benchmarks/step_ab.py,
    figures in the README, "On a shared machine"). Must run before torch is imported (libgomp reads it once).
    """
    if "GOMP_SPINCOUNT" in environ or "OMP_WAIT_POLICY" in environ:
        return False
    environ["GOMP_SPINCOUNT"] = SPINCOUNT
    return True
