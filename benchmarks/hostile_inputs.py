"""Hostile-input audit: every config field of the stage presets and the Gaussian backbone, given a value of the
wrong type and an out-of-range number, and a set of broken transforms.json datasets, each run through
``stage=check`` as the console script would (in-process, for speed). Prints one row per case and a summary:
clear errors (exit 2, one ``error:`` line), tracebacks (a bug), accepted values (listed, to review), and
inputs changed or files written outside the run folder (must be 0).

    .venv/bin/python benchmarks/hostile_inputs.py [--out DIR]

The cases the issue listed are tests (tests/test_bad_inputs*.py); this script widens the net.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import io
import json
import sys
import tempfile
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from conftest import write_transforms_scene


def config_cases() -> list[tuple[str, list[str]]]:
    """``(name, overrides)``: each field of the validated config dataclasses, a string and -7."""
    from arcsem.backbones.gs2d.backbone import GS2DBackbone

    from arcsem.configs import ActConfig, ColorizeConfig, EvalConfig, ReaderOptions, TrainConfig

    groups = {"train": TrainConfig, "train.eval": EvalConfig, "colorize": ColorizeConfig, "act": ActConfig,
              "dataset": ReaderOptions, "backbone": GS2DBackbone.Config}
    cases = []
    for prefix, schema in groups.items():
        for f in dataclasses.fields(schema):
            if f.type in ("int", "float", "int | None", "float | None", "str", "bool"):
                for value in ("abc", "-7") if f.type != "str" else ("-7", "zzz"):
                    key = f"{prefix}.{f.name}"
                    cases.append((f"{key}={value}", [f"++{key}={value}"]))
    cases += [(f"{k}={v}", [f"{k}={v}"]) for k, v in (("seed", "1.5"), ("seed", "abc"), ("threads", "-1"),
                                                     ("device", "cuda:3"), ("device", "gpu"), ("stage", "x"))]
    return cases


def dataset_cases() -> dict[str, object]:
    """name -> edit(meta) of a valid tiny transforms.json."""
    def frame(**kw):
        return lambda m: m["frames"][0].update(**kw)
    return {
        "no frames": lambda m: m.update(frames=[]), "frames not a list": lambda m: m.update(frames={}),
        "frame without file_path": lambda m: m["frames"][0].pop("file_path"),
        "missing image": frame(file_path="nope.png"), "file_path a folder": frame(file_path="."),
        "matrix 3x3": frame(transform_matrix=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        "matrix strings": frame(transform_matrix=[["a"] * 4] * 4), "matrix NaN": frame(transform_matrix=[[float("nan")] * 4] * 4),
        "reflection": frame(transform_matrix=[[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]),
        "w zero": lambda m: m.update(w=0), "h string": lambda m: m.update(h="x"), "cx NaN": lambda m: m.update(cx=float("nan")),
        "fl_x null": lambda m: m.update(fl_x=None), "camera_angle_x 4": lambda m: (m.pop("fl_x"), m.update(camera_angle_x=4.0)),
        "camera_model FISHEYE": lambda m: m.update(camera_model="FISHEYE"), "k2 nonzero": lambda m: m.update(k2=0.1),
        "split bogus": frame(split="val"), "mask missing": frame(mask_path="nomask.png"),
        "depth wrong shape": None, "aabb inverted": lambda m: m.update(aabb=[[1, 1, 1], [0, 0, 0]]),
        "aabb junk": lambda m: m.update(aabb="x"), "reference_sets junk": lambda m: m.update(reference_sets=[1]),
        "reference_sets unknown view": lambda m: m.update(reference_sets={"one": ["nope"]}),
        "ply missing": lambda m: m.update(ply_file_path="nope.ply"), "specimen_size -1": lambda m: m.update(specimen_size=-1),
        "duplicate frame": lambda m: m["frames"].append(dict(m["frames"][0])),
    }


def _hashes(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*") if p.is_file()}


def run_case(tmp: Path, name: str, overrides: list[str], edit=None) -> dict:
    """Compose and run one ``stage=check`` as the CLI does; classify the outcome."""
    from hydra import compose, initialize_config_module

    from arcsem import app
    from arcsem.cli.errors import call_reporting_errors

    case = tmp / f"case{abs(hash(name)) % 10**8}"
    scene = write_transforms_scene(case / "scene", n=4, w=32, h=24)
    if callable(edit):
        meta = json.loads(scene.read_text())
        edit(meta)
        scene.write_text(json.dumps(meta))
    elif name.endswith("depth wrong shape"):
        import numpy as np
        np.save(case / "scene" / "d.npy", np.zeros((3, 3), np.float32))
        meta = json.loads(scene.read_text())
        meta["frames"][0]["depth_path"] = "d.npy"
        scene.write_text(json.dumps(meta))
    before, outside_before = _hashes(case / "scene"), sorted(p.name for p in case.iterdir())
    err = io.StringIO()
    outcome = "accepted"
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            with initialize_config_module("arcsem.conf", version_base="1.3"):
                def call():
                    line = ["dataset=transforms", f"dataset.path={case / 'scene'}", "stage=check", *overrides]
                    return app.run(compose("config", overrides=line), run_dir=case / "run", overrides=line)
                code = call_reporting_errors(call)
            lines = [ln for ln in err.getvalue().splitlines() if ln.startswith("error:")]
            if code == 2:
                outcome = "clear error" if len(lines) == 1 else "unclear error"
        except Exception:  # noqa: BLE001 (a traceback is what this audit looks for)
            outcome, lines = "traceback", [traceback.format_exc().strip().splitlines()[-1]]
    changed = _hashes(case / "scene") != before
    outside = sorted({p.name for p in case.iterdir()} - set(outside_before) - {"run"})
    return {"case": name, "outcome": outcome, "message": (lines or [""])[0][:160], "inputs_changed": changed,
            "written_outside": outside}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="write the rows as JSON here")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, overrides in config_cases():
            rows.append(run_case(Path(tmp), name, overrides))
        for name, edit in dataset_cases().items():
            rows.append(run_case(Path(tmp), f"dataset: {name}", [], edit))
    for r in rows:
        print(f"{r['outcome']:13s} {r['case']:40s} {r['message']}")
    count = lambda o: sum(r["outcome"] == o for r in rows)
    print(f"\n{len(rows)} cases: {count('clear error')} clear errors, {count('traceback')} tracebacks, "
          f"{count('unclear error')} unclear errors, {count('accepted')} accepted (review them above); "
          f"inputs changed: {sum(r['inputs_changed'] for r in rows)}, "
          f"files written outside the run folder: {sum(bool(r['written_outside']) for r in rows)}")
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
