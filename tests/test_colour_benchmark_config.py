"""experiment=colorization_benchmark composes with every colour scene (built-in and public; no training)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_module

from arcsem.data import check_dataset_config
from arcsem.report.collect import STUDIES

CONF = Path(__file__).resolve().parents[1] / "conf"
SWEEP = yaml.safe_load((CONF / "experiment/colorization_benchmark.yaml").read_text())["hydra"]["sweeper"]["params"]
SCENES = SWEEP["dataset"].split(",")
PUBLIC = {"public_fox": "fox", "public_chair": "chair"}  # dataset option -> folder under benchmark_root


def _compose(*overrides: str):
    from arcsem.schemas import setup

    setup()
    with initialize_config_module("arcsem.conf", version_base="1.3"):
        return compose("config", overrides=["experiment=colorization_benchmark", *overrides])


def test_the_benchmark_sweeps_five_scenes_and_lists_the_held_out_one_on_its_own():
    assert SCENES == ["synthetic", "diatom", "parts", "public_fox", "public_chair"]
    labels = list(STUDIES["colorization_benchmark"].rows.items())
    held = [k for k, v in labels if "held out" in v]
    assert held and all(k.startswith("public_chair/") for k in held)
    assert [k for k, _ in labels[-len(held):]] == held  # its rows come last, as a group of their own
    rows = {f"{d}/{r}/{a}" for d in SCENES for r in SWEEP["colorize.references"].split(",")
            for a in SWEEP["ablation"].split(",")}
    assert rows <= set(STUDIES["colorization_benchmark"].rows)


@pytest.mark.parametrize("scene", SCENES)
def test_the_benchmark_composes_with_every_scene(scene):
    cfg = _compose(f"dataset={scene}", "benchmark_root=/data/colour")
    check_dataset_config(cfg.dataset)  # keys and generator parameters valid for the dataset kind
    assert cfg.stage == "all" and cfg.share_stage1 and cfg.act.enabled
    if scene in PUBLIC:
        assert cfg.dataset.kind == "transforms" and cfg.dataset.path == f"/data/colour/{PUBLIC[scene]}"
    else:
        assert cfg.dataset.kind == "synthetic"
        assert cfg.dataset.get("specimen", "grain") == {"synthetic": "grain"}.get(scene, scene)


@pytest.mark.parametrize("experiment", [False, True])
def test_a_public_scene_defaults_to_the_cache_root_of_the_run(experiment, monkeypatch, tmp_path):
    """Not a folder of one machine: under cache_dir, else $ARCSEM_CACHE (what benchmarks/colour_scenes.py writes)."""
    from arcsem.schemas import setup

    setup()
    exp = ["experiment=colorization_benchmark"] if experiment else []
    monkeypatch.setenv("ARCSEM_CACHE", str(tmp_path / "env"))
    with initialize_config_module("arcsem.conf", version_base="1.3"):
        by_env = compose("config", overrides=[*exp, "dataset=public_chair"])
        by_key = compose("config", overrides=[*exp, "dataset=public_chair", "cache_dir=/data/cache"])
    assert by_env.dataset.path == f"{tmp_path}/env/colour_scenes/chair"
    assert by_key.dataset.path == "/data/cache/colour_scenes/chair"


def test_a_missing_public_scene_says_how_to_write_it(tmp_path):
    from arcsem.data import load_scene
    from arcsem.errors import DataError

    cfg = _compose("dataset=public_fox", f"benchmark_root={tmp_path}/scenes")
    with pytest.raises(DataError) as err:
        load_scene(cfg.dataset)
    assert str(err.value) == (f"dataset path does not exist: {tmp_path}/scenes/fox (`python benchmarks/colour_scenes.py "
                              f"--out {tmp_path}/scenes` writes it)")
