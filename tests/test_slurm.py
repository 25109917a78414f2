"""Studies through ``hydra/launcher=submitit_slurm`` on a real single-node SLURM (tests/slurm/cluster.sh).

Jobs run as SLURM tasks (two at a time: one core each on this 2-core node) of the real ``arcsem`` command on a
tiny built-in scene: a sweep's table equals the same sweep's through ``joblib``; a job killed with ``scancel``
resumes from its checkpoint when the sweep is submitted again; two tasks racing for one shared stage-1 model
train it once. The cluster starts once for these tests and is stopped after them, leaving no daemon running.
Where it cannot start (no SLURM installed: ``make slurm``; not root) the tests are skipped and say why;
``ARCSEM_REQUIRE_SLURM=1`` (CI) turns that into a failure.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from conftest import arcsem_command

from arcsem.report import build_report

pytestmark = [pytest.mark.slurm, pytest.mark.slow, pytest.mark.xdist_group("slurm")]

CLUSTER = Path(__file__).resolve().parent / "slurm" / "cluster.sh"
DAEMONS = ("slurmd", "slurmctld", "slurmdbd", "mariadbd", "munged")
TOOLS = ("munged", "slurmctld", "slurmd", "slurmdbd", "sbatch", "scancel", "squeue", "sacct", "mariadbd")

# tiny jobs: a 48x32 built-in scene with 12 views, one thread, no video, LPIPS, mesh or TCM/CCM
SCENE = ["dataset.width=48", "dataset.height=32", "dataset.n_horizontal=8", "dataset.n_vertical=4"]
TINY = [*SCENE, "threads=1", "train.width=null", "train.steps=40", "backbone.random_init_points=200",
        "train.eval.video=false", "train.eval.lpips=false", "train.progress=false", "mesh.enabled=false",
        "colorize.steps=10", "colorize.eval.video=false", "colorize.eval.lpips=false", "colorize.progress=false",
        "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0", "hydra.launcher.timeout_min=5"]


def _cannot_start(why: str) -> None:
    if os.environ.get("ARCSEM_REQUIRE_SLURM") == "1":
        pytest.fail(f"ARCSEM_REQUIRE_SLURM=1 but the test cluster cannot start: {why}")
    pytest.skip(f"no test SLURM cluster: {why}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.fixture(scope="session")
def slurm_env(tmp_path_factory) -> dict[str, str]:
    """Start the cluster (session); the environment for commands that use it. Stopped at the end, nothing left."""
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        _cannot_start(f"{', '.join(missing)} not installed (make slurm)")
    if os.geteuid() != 0:
        _cannot_start("its daemons run as root, and this is not root")
    proc = subprocess.run(["bash", str(CLUSTER), "start"], capture_output=True, text=True, timeout=180, check=False)
    if proc.returncode != 0:
        _cannot_start((proc.stderr.strip().splitlines() or ["cluster.sh start failed"])[-1])
    folder = Path(proc.stdout.split()[-1])
    pids = {d: int((folder / "run" / f"{d}.pid").read_text()) for d in DAEMONS}
    cache = tmp_path_factory.mktemp("slurm_cache")  # scenes, generated once for every sweep of these tests
    yield {**os.environ, "SLURM_CONF": str(folder / "etc" / "slurm.conf"), "ARCSEM_CACHE": str(cache)}
    stop = subprocess.run(["bash", str(CLUSTER), "stop", str(folder)], capture_output=True, text=True, timeout=120,
                          check=False)
    assert stop.returncode == 0, stop.stderr
    left = {d: pid for d, pid in pids.items() if _alive(pid)}
    assert not left, f"still running after the cluster stopped: {left}"


def _sweep(env: dict, where: Path, launcher: str, *args: str, timeout: float = 240,
           wait: bool = True) -> subprocess.CompletedProcess | subprocess.Popen:
    """``arcsem experiment=reference_count`` (tiny) through ``launcher`` into ``where/sweep``, stage-1 cache
    ``where/cache``; returns the finished process, or (``wait=False``) the running one."""
    cmd = [*arcsem_command(), "experiment=reference_count", f"hydra/launcher={launcher}", *TINY,
           f"hydra.sweep.dir={where / 'sweep'}", f"cache_dir={where / 'cache'}", *args]
    if launcher != "submitit_slurm":
        cmd = [c for c in cmd if not c.startswith("hydra.launcher.timeout_min")]
    if not wait:
        return subprocess.Popen(cmd, cwd=where.parent, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True)
    return subprocess.run(cmd, cwd=where.parent, env=env, capture_output=True, text=True, timeout=timeout,
                          check=False)


def _queue(env: dict) -> list[str]:
    """``squeue``: the cluster's jobs as ``<array job>_<task> <state>``."""
    out = subprocess.run(["squeue", "-h", "-o", "%F_%K %T"], env=env, capture_output=True, text=True, timeout=30,
                         check=True).stdout
    return out.split("\n")[:-1]


def _wait_for_empty_queue(env: dict, timeout: float = 60) -> None:
    t_end = time.monotonic() + timeout
    while _queue(env):
        assert time.monotonic() < t_end, _queue(env)
        time.sleep(0.5)


def _metrics(sweep: Path) -> dict[str, dict]:
    """``{"<references>/<backbone>": metrics.json + its folder ("run_dir")}`` of the sweep's finished jobs."""
    out = {}
    for path in sorted(sweep.glob("*/metrics.json")):
        m = {**json.loads(path.read_text()), "run_dir": path.parent}
        over = dict(o.split("=", 1) for o in m["overrides"])
        out[f"{over['colorize.references']}/{m['backbone']}"] = m
    return out


def _table(sweep: Path) -> str:
    """The study's generated table (``arcsem-report``'s ``reference_count.md``)."""
    page = build_report([sweep], out=sweep.parent / "report")
    return (page.parent / "reference_count.md").read_text()


def test_slurm_sweep_table_equals_joblib_sweep(slurm_env, tmp_path):
    """4 SLURM jobs, 2 backbones, each stage-1 model trained once and shared by 2 jobs; the table as joblib's."""
    grid = ["backbone=gs2d,gs3d", "colorize.references=five,two"]
    slurm = _sweep(slurm_env, tmp_path / "slurm", "submitit_slurm", *grid)
    assert slurm.returncode == 0, slurm.stdout[-2000:] + slurm.stderr[-3000:]
    tasks = sorted((tmp_path / "slurm" / "sweep" / ".submitit").glob("*_*/*_result.pkl"))  # <array job>_<task>
    assert [p.parent.name.split("_")[1] for p in tasks] == ["0", "1", "2", "3"], tasks
    assert "#SBATCH --cpus-per-task=1" in next((tmp_path / "slurm" / "sweep" / ".submitit").glob("*/*.sh")).read_text()
    local = _sweep(slurm_env, tmp_path / "joblib", "joblib", *grid, "hydra.launcher.n_jobs=2")
    assert local.returncode == 0, local.stderr[-3000:]
    runs = _metrics(tmp_path / "slurm" / "sweep")
    assert sorted(runs) == ["five/gs2d", "five/gs3d", "two/gs2d", "two/gs3d"]
    assert all(m["status"] == "complete" for m in runs.values())
    for backbone in ("gs2d", "gs3d"):  # one trained, the other reused it from the shared cache
        pair = [runs[f"{r}/{backbone}"] for r in ("five", "two")]
        assert sorted(m["stage1_reused"] for m in pair) == [False, True]
        assert pair[0]["stage1_dir"] == pair[1]["stage1_dir"]
    assert len(list((tmp_path / "slurm" / "cache" / "stage1").glob("*/DONE"))) == 2
    local_runs = _metrics(tmp_path / "joblib" / "sweep")
    for key, m in runs.items():  # every job's held-out colour metrics, to the last digit
        assert json.dumps(m["stage2"]["test"]) == json.dumps(local_runs[key]["stage2"]["test"]), key
    table = _table(tmp_path / "slurm" / "sweep")
    assert "| 5 |" in table and "| 2 |" in table and "missing" not in table
    assert table == _table(tmp_path / "joblib" / "sweep")


def _wait_for_file(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    t_end = time.monotonic() + timeout
    while not path.is_file():
        assert proc.poll() is None, proc.stdout.read()[-3000:]
        assert time.monotonic() < t_end, f"{path} never written"
        time.sleep(0.05)


def test_scancelled_job_resumes_when_the_sweep_is_submitted_again(slurm_env, tmp_path):
    """Job 0 killed (``scancel``) after its first stage-1 checkpoint; the same command again: job 0 resumes from
    that checkpoint, and the table has both rows."""
    where = tmp_path / "run"
    args = ["backbone=gs2d", "colorize.references=five,two", "share_stage1=false", "train.steps=300",
            "train.checkpoint_every=10"]
    proc = _sweep(slurm_env, where, "submitit_slurm", *args, wait=False)
    _wait_for_file(where / "sweep" / "0" / "checkpoints" / "last.pt", proc)
    job0 = next(j.split()[0] for j in _queue(slurm_env) if j.endswith("_0 RUNNING"))
    subprocess.run(["scancel", job0], env=slurm_env, check=True, timeout=30)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode != 0, out[-3000:]  # the sweep reports the cancelled job
    _wait_for_empty_queue(slurm_env)  # job 1 finishes (the launcher stopped waiting at job 0)
    assert not (where / "sweep" / "0" / "metrics.json").exists() or json.loads(
        (where / "sweep" / "0" / "metrics.json").read_text())["status"] != "complete"
    again = _sweep(slurm_env, where, "submitit_slurm", *args)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-3000:]
    runs = _metrics(where / "sweep")
    resumed = runs["five/gs2d"]["stage1"]["resumed_from"]
    assert resumed is not None and 0 < resumed < 300 and resumed % 10 == 0, resumed
    assert runs["two/gs2d"]["stage1"]["resumed_from"] == 300  # finished before: nothing retrained
    assert all(m["status"] == "complete" for m in runs.values())
    table = _table(where / "sweep")
    assert "| 5 |" in table and "| 2 |" in table and "missing" not in table


def test_two_slurm_tasks_racing_for_one_stage1_model_train_it_once(slurm_env, tmp_path):
    """Two tasks start together on the node's two cores and need the same shared stage-1 model: one trains it,
    the other waits on the lock in the cache (across SLURM tasks) and reuses it."""
    where = tmp_path / "race"
    res = _sweep(slurm_env, where, "submitit_slurm", "backbone=gs2d", "colorize.references=five,two",
                 "train.steps=200")
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    runs = _metrics(where / "sweep")
    assert sorted(m["stage1_reused"] for m in runs.values()) == [False, True]
    logs = {m["stage1_reused"]: (m["run_dir"] / "main.log").read_text() for m in runs.values()}
    assert "waiting for the shared stage-1 model" in logs[True]  # it came while the other task trained
    assert "waiting for" not in logs[False]
    done = list((where / "cache" / "stage1").glob("*/DONE"))
    assert len(done) == 1 and (done[0].parent / "checkpoints" / "last.pt").is_file()
