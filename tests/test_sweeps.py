"""Study configs compose; tiny sweeps run through the joblib and submitit_local launchers.

The sweeps use a minimal Hydra app written here (``arcsem``'s own app is exercised by its tests); it
shares a fake "stage 1" through :func:`arcsem.share.ensure_stage1` and writes ``metrics.json`` like
``arcsem`` does, so the sweep -> stage-1 sharing -> ``arcsem-report`` path is tested end to end.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from arcsem.report.collect import STUDIES, collect

CONF = Path(__file__).resolve().parents[1] / "conf"
STUBS = ["dataset/synthetic", "train/quick", "train/paper", "colorize/quick", "colorize/paper"]


@pytest.fixture(scope="module")
def conf_dir(tmp_path_factory) -> Path:
    """The real conf tree; group options other helpers have not written yet are stubbed (tagged)."""
    dst = tmp_path_factory.mktemp("conf") / "conf"
    shutil.copytree(CONF, dst)
    for stub in STUBS:
        path = dst / f"{stub}.yaml"
        if not path.exists():
            path.write_text(f"stub: {stub}\nreferences: five\n")
    return dst


def _compose(conf_dir: Path, overrides: list[str]):
    from hydra import compose, initialize_config_dir

    from arcsem.schemas import setup

    setup()  # the schemas and resolvers the configs name (as the arcsem command does at start-up)

    with initialize_config_dir(str(conf_dir), version_base=None):
        return compose("config", overrides=overrides, return_hydra_config=True)


# variant -> (backbone, ACT enabled)
GRAY_ROWS = {"plenoxels": ("plenoxels", False), "gs3d": ("gs3d", False), "gs2d": ("gs2d", False),
             "gs2d_act": ("gs2d", True)}


@pytest.mark.parametrize("preset", ["quick", "paper"])
@pytest.mark.parametrize("variant", list(GRAY_ROWS))
def test_grayscale_rows_compose(conf_dir, variant, preset):
    cfg = _compose(conf_dir, ["experiment=grayscale_comparison", f"variant={variant}", f"preset={preset}"])
    assert (cfg.backbone.name, cfg.act.enabled) == GRAY_ROWS[variant]
    assert cfg.stage == "gray" and str(cfg.hydra.mode) == "RunMode.MULTIRUN"
    assert cfg.hydra.sweeper.params["variant"].split(",") == list(STUDIES["grayscale_comparison"].rows)
    assert cfg.hydra.runtime.choices["train"] == preset and cfg.hydra.runtime.choices["colorize"] == preset


# ablation -> (ACT enabled, TCM on, CCM on); a term is on unless its weight is 0 (absent: the preset's)
ABLATIONS = {"full": (True, True, True), "no_tcm": (True, False, True), "no_ccm": (True, True, False),
             "no_act": (False, True, True), "no_all": (False, False, False)}


@pytest.mark.parametrize("preset", ["quick", "paper"])
@pytest.mark.parametrize("ablation", list(ABLATIONS))
def test_ablation_rows_compose(conf_dir, ablation, preset):
    cfg = _compose(conf_dir, ["experiment=colorization_ablation", f"ablation={ablation}", f"preset={preset}"])
    losses = cfg.colorize.get("losses") or {}
    on = [(losses.get(t) or {}).get("weight", 1.0) != 0 for t in ("tcm", "ccm")]
    assert (cfg.act.enabled, *on) == ABLATIONS[ablation]
    assert (losses.get("pseudo_color") or {}).get("weight", 1.0) != 0  # pseudo-colours stay in every row
    assert cfg.stage == "all" and cfg.colorize.references == "five" and cfg.backbone.name == "gs2d"
    assert cfg.hydra.sweeper.params["ablation"].split(",") == list(STUDIES["colorization_ablation"].rows)


def test_reference_count_composes_and_cli_wins(conf_dir):
    cfg = _compose(conf_dir, ["experiment=reference_count", "colorize.references=two", "preset=paper",
                              "train=quick"])
    assert cfg.colorize.references == "two" and cfg.act.enabled and cfg.stage == "all"
    assert cfg.hydra.runtime.choices["train"] == "quick"  # the command line beats the preset
    assert cfg.hydra.runtime.choices["colorize"] == "paper"
    assert cfg.hydra.sweeper.params["colorize.references"] == "five,four,three,two,one"
    assert _compose(conf_dir, ["experiment=reference_count", "backbone=gs3d"]).backbone.name == "gs3d"


APP = '''
import json, os, time
from pathlib import Path
import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf
from arcsem.share import ensure_stage1

@hydra.main(config_path="conf", config_name="config", version_base=None)
def main(cfg):
    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    if cfg.colorize.references == cfg.fail_on:  # a hard stop (OOM, kill): later jobs never start
        print("job failed on purpose", flush=True)
        os._exit(3)
    def train(path):
        with open(os.environ["COUNT_FILE"], "a") as fh:
            fh.write(f"{os.getpid()}\\n")
        time.sleep(cfg.train_s)
        (path / "model.txt").write_text("stage1")
    path, trained = ensure_stage1(cfg, train)
    OmegaConf.save(cfg, out / "config.yaml")
    psnr = {"five": 26.0, "two": 24.0, "one": 22.0}[cfg.colorize.references]
    metrics = {"seed": cfg.seed, "overrides": list(hc.overrides.task), "shared": str(path),
               "trained_here": trained, "stage2": {"test": {"psnr": psnr, "ssim": 0.9, "lpips": 0.2},
               "train_nonref": {"psnr": psnr + 1, "ssim": 0.9, "lpips": 0.2}, "features": "imagenet"}}
    (out / "metrics.json").write_text(json.dumps(metrics))

if __name__ == "__main__":
    main()
'''


def _app(tmp: Path, train_s: float = 0.0, fail_on: str = "none") -> Path:
    (tmp / "conf").mkdir(parents=True)
    (tmp / "app.py").write_text(textwrap.dedent(APP))
    cfg = {"defaults": ["_self_", {"experiment": None}], "seed": 0, "dataset": {"name": "tiny"},
           "backbone": {"name": "gs2d"}, "act": {"enabled": True}, "train": {"steps": 1},
           "colorize": {"references": "five"}, "train_s": train_s, "fail_on": fail_on, "cache_dir": str(tmp / "cache")}
    (tmp / "conf" / "config.yaml").write_text(yaml.safe_dump(cfg))
    # the real study file without its defaults list (the tiny app has no groups): its `hydra.mode:
    # MULTIRUN` and sweeper params must start the sweep without `-m`
    study = yaml.safe_load((CONF / "experiment" / "reference_count.yaml").read_text())
    study.pop("defaults")
    (tmp / "conf" / "experiment").mkdir()
    (tmp / "conf" / "experiment" / "reference_count.yaml").write_text("# @package _global_\n" + yaml.safe_dump(study))
    return tmp


def _sweep(app: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "COUNT_FILE": str(app / "count.txt"), "HYDRA_FULL_ERROR": "1"}
    return subprocess.run([sys.executable, str(app / "app.py"), "experiment=reference_count",
                           f"hydra.sweep.dir={app / 'multirun'}", *args],
                          cwd=app, env=env, capture_output=True, text=True, timeout=110, check=False)


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["joblib", "submitit_local"])
def test_two_job_sweep_shares_stage1_and_reports(tmp_path, launcher):
    app = _app(tmp_path, train_s=2.0)
    extra = ["hydra.launcher.n_jobs=2"] if launcher == "joblib" else ["hydra.launcher.timeout_min=2"]
    res = _sweep(app, f"hydra/launcher={launcher}", "colorize.references=five,two", *extra)
    assert res.returncode == 0, res.stderr[-3000:]
    coll = collect([app / "multirun"])
    assert sorted(coll.runs["row"]) == ["five", "two"] and coll.missing == []
    assert set(coll.runs["study"]) == {"reference_count"}
    # one stage-1 training for both jobs: one trained, the other waited on the lock and reused it
    assert (app / "count.txt").read_text().count("\n") == 1
    assert sorted(coll.runs["trained_here"]) == [False, True] and coll.runs["shared"].nunique() == 1
    from arcsem.report import build_report

    page = build_report([app / "multirun"])
    md = (page.parent / "reference_count.md").read_text()
    assert "| 5 | **27.00** |" in md and "| 2 | 25.00 |" in md


def test_interrupted_sweep_lists_missing_jobs(tmp_path):
    """Basic launcher, job 1 of 3 killed: job 0 reported, job 1 (folder, no metrics) and 2 (never run) missing."""
    app = _app(tmp_path, fail_on="two")
    res = _sweep(app, "colorize.references=five,two,one")
    assert res.returncode == 3 and "job failed on purpose" in res.stdout
    coll = collect([app / "multirun"])
    assert list(coll.runs["row"]) == ["five"]
    missing = {m.row: m for m in coll.missing}
    assert set(missing) == {"two", "one"}
    assert missing["two"].job_dir is not None and missing["one"].job_dir is None
    from arcsem.report import build_report

    md = (build_report([app / "multirun"]).parent / "reference_count.md").read_text()
    assert "| 2 | missing |" in md and "| 1 | missing |" in md and md.count("missing job:") == 2


def _real_app_ready() -> str | None:
    """Why the real ``arcsem`` app cannot run a study yet (missing conf groups), or None."""
    from hydra import compose, initialize_config_module
    from hydra.errors import HydraException

    try:
        with initialize_config_module("arcsem.conf", version_base=None):
            compose("config", overrides=["experiment=grayscale_comparison", "dataset=transforms"])
    except HydraException as err:
        return str(err).splitlines()[0]
    return None


@pytest.mark.slow
def test_real_app_study_check_sweep(tmp_path, tiny_transforms):
    """``arcsem experiment=grayscale_comparison stage=check`` (2 rows, joblib) then ``arcsem-report``."""
    why = _real_app_ready()
    if why:
        pytest.skip(f"the study does not compose with the real conf yet: {why}")
    scene = tiny_transforms(n=6, w=32, h=24)
    exe = Path(sys.executable).parent / "arcsem"
    res = subprocess.run([str(exe), "experiment=grayscale_comparison", "stage=check", "dataset=transforms",
                          f"dataset.path={scene}", "variant=gs2d,gs2d_act", "hydra/launcher=joblib",
                          "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path / 'mr'}"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=110, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    coll = collect([tmp_path / "mr"])
    assert sorted(coll.runs["row"]) == ["gs2d", "gs2d_act"] and coll.missing == []
    assert set(coll.runs["study"]) == {"grayscale_comparison"} and set(coll.runs["backbone"]) == {"gs2d"}
    rep = subprocess.run([str(exe.parent / "arcsem-report"), str(tmp_path / "mr")], capture_output=True,
                         text=True, timeout=60, check=False)
    assert rep.returncode == 0, rep.stderr
    md = (tmp_path / "mr" / "report" / "grayscale_comparison.md").read_text()
    assert "| 2DGS + ACT |" in md and "36.32" in md


@pytest.mark.parametrize("launcher, target", [("joblib", "JoblibLauncher"), ("submitit_local", "LocalLauncher"),
                                              ("submitit_slurm", "SlurmLauncher"), ("basic", "BasicLauncher")])
def test_studies_compose_with_every_launcher(conf_dir, launcher, target):
    cfg = _compose(conf_dir, ["experiment=reference_count", f"hydra/launcher={launcher}"])
    assert cfg.hydra.launcher._target_.endswith(target)


@pytest.mark.parametrize("ablation", ["full", "pseudo_only"])
def test_colorization_benchmark_composes_both_stage2_rows(conf_dir, ablation):
    """The benchmark's rows: the default stage 2 (every addition on) and pseudo-colours alone (the paper's), over
    both built-in colour scenes, one/three/five references and three seeds; every row is a row of its table."""
    cfg = _compose(conf_dir, ["experiment=colorization_benchmark", f"ablation={ablation}", "dataset=diatom"])
    c = cfg.colorize
    on = [(c.losses.get(t) or {}).get("weight", 1.0) != 0 for t in ("tcm", "ccm")]
    default = ablation == "full"
    assert on == [default, default] and cfg.act.enabled and cfg.stage == "all" and cfg.dataset.specimen == "diatom"
    assert (c.get("validate", "auto"), c.get("shading", "auto"), c.get("prior", "grey")) == (
        ("auto", "auto", "grey") if default else ("off", "off", "off"))
    p = cfg.hydra.sweeper.params
    rows = [f"{d}/{r}/{a}" for d in p["dataset"].split(",") for r in p["colorize.references"].split(",")
            for a in p["ablation"].split(",")]
    assert rows and set(rows) <= set(STUDIES["colorization_benchmark"].rows) and p["seed"] == "0,1,2"


@pytest.mark.parametrize("overrides, cpus, gpus", [([], 4, None), (["threads=2", "device=cuda"], 2, 1),
                                                    (["threads=1", "device=cuda:1"], 1, 2)])
def test_slurm_launcher_asks_for_the_jobs_threads_and_gpus(overrides, cpus, gpus):
    """conf/hydra/launcher/submitit_slurm.yaml: cores from ``threads`` (4 when null), GPUs from ``device``."""
    from hydra import compose, initialize_config_module

    with initialize_config_module("arcsem.conf", version_base=None):
        cfg = compose("config", overrides=["experiment=reference_count", "hydra/launcher=submitit_slurm", *overrides],
                      return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert (launcher.cpus_per_task, launcher.gpus_per_task, launcher.timeout_min) == (cpus, gpus, 360)
    assert launcher._target_.endswith("SlurmLauncher")
