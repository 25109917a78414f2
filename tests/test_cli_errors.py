"""Bad input ends with one ``error:`` line naming the file/view/key, exit code 2, no traceback.

Each case runs the ``arcsem`` console script as a subprocess with ``stage=check`` (load the scene,
build the backbone, train nothing) on a tiny hand-written dataset.
"""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import arcsem_command, missing_defaults, write_transforms_scene

pytestmark = pytest.mark.slow  # each case starts the console script (a few seconds of imports)


def run_cli(tmp_path: Path, *overrides: str, env: dict | None = None) -> subprocess.CompletedProcess:
    args = [*arcsem_command(), "stage=check", f"hydra.run.dir={tmp_path / 'run'}", *missing_defaults(overrides),
            *overrides]
    full_env = {k: v for k, v in os.environ.items() if k not in ("ARCSEM_DEBUG", "HYDRA_FULL_ERROR")}
    full_env.update(env or {})
    return subprocess.run(args, capture_output=True, text=True, timeout=300, cwd=tmp_path, env=full_env,
                          check=False)


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], proc.stderr
    assert not any("Error executing job" in ln for ln in lines), proc.stderr  # Hydra's own line: not shown
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]


def dataset(tmp_path: Path, edit=None) -> list[str]:
    path = write_transforms_scene(tmp_path / "scene", n=3)
    if edit is not None:
        edit(path)
    return ["dataset=transforms", f"dataset.path={path.parent}"]


def edit_json(change):
    def edit(path: Path) -> None:
        meta = json.loads(path.read_text())
        change(meta)
        path.write_text(json.dumps(meta))
    return edit


def test_missing_image_file(tmp_path):
    ds = dataset(tmp_path, edit_json(lambda m: m["frames"][1].update(file_path="gone.png")))
    assert_one_line_error(run_cli(tmp_path, *ds), "frame 1", "gone.png", "not found")


def test_image_size_differs_from_camera(tmp_path):
    ds = dataset(tmp_path, lambda p: cv2.imwrite(str(p.parent / "view_02.png"), np.zeros((7, 16), np.uint8)))
    assert_one_line_error(run_cli(tmp_path, *ds), "view 'view_02'", "view_02.png", "16x7", "16x12")


def test_unknown_camera_model(tmp_path):
    ds = dataset(tmp_path, edit_json(lambda m: m.update(camera_model="FISHEYE_X")))
    assert_one_line_error(run_cli(tmp_path, *ds), "transforms.json", "unknown camera_model 'FISHEYE_X'")


def test_malformed_json(tmp_path):
    ds = dataset(tmp_path, lambda p: p.write_text('{"fl_x": 20, "frames": [ {"file_path": "a.png",, } ]}'))
    assert_one_line_error(run_cli(tmp_path, *ds), "transforms.json", "malformed JSON at line 1")


def test_dataset_path_does_not_exist(tmp_path):
    proc = run_cli(tmp_path, "dataset=transforms", f"dataset.path={tmp_path / 'nowhere'}")
    assert_one_line_error(proc, "does not exist", str(tmp_path / "nowhere"))


@pytest.mark.parametrize("override,needles", [
    # Hydra: no such config option; its options named without the schemas Hydra lists among them
    ("backbone=gs4d", ["backbone=gs4d: no such option; did you mean backbone=gs3d? available: gs2d, gs3d, "]),
    ("experiment=dem", ["experiment=dem: no such option; did you mean experiment=demo?"]),
    # a study's preset on a single run: what a run takes instead
    ("preset=paper", ["preset=paper: a preset is chosen on a study", "train=paper colorize=paper", "+preset=paper"]),
    ("backbone.name=nope", ["unknown backbone 'nope'", "available: ", "gs2d"]),  # registry
])
def test_unknown_plugin(tmp_path, override, needles):
    line = assert_one_line_error(run_cli(tmp_path, *dataset(tmp_path), override), *needles)
    assert "_schema" not in line and "search path" not in line


@pytest.mark.parametrize("override,needles", [
    ("seeed=3", ["'seeed'"]),  # Hydra (struct config)
    ("+backbone.sh_degre=2", ["unknown key(s) 'sh_degre'", "valid keys:"]),  # plugin Config dataclass
    ("threads=0", ["threads: expected a positive integer or null, got 0"]),  # a bad value
    ("act.solvr=adam", ["act.solvr: unknown key", "init_noise"]),  # the act group (ActConfig schema)
    # a loss key: passed on as ++ (not Hydra's "use +"), then named by the loss's Config
    ("train.losses.dssim.implx=torch", ["loss 'dssim': unknown key(s) 'implx'", "valid keys:", "impl"]),
    # the optional CUDA rasteriser on the CPU: refused before anything is read
    ("backbone.rasterizer=gsplat", ["backbone.rasterizer=gsplat needs the model on a CUDA device", "=auto"]),
])
def test_mistyped_config_key(tmp_path, override, needles):
    assert_one_line_error(run_cli(tmp_path, *dataset(tmp_path), "backbone=gs3d", override), *needles)


@pytest.mark.parametrize("how", ["override", "env"])
def test_debug_shows_traceback(tmp_path, how):
    ds = dataset(tmp_path, lambda p: p.write_text("{ not json"))
    proc = run_cli(tmp_path, *ds, *(["debug=true"] if how == "override" else []),
                   env={"ARCSEM_DEBUG": "1"} if how == "env" else None)
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr and "DataError" in proc.stderr and "malformed JSON" in proc.stderr
