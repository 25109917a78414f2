"""Hostile-input audit: every config field of the stage presets and the Gaussian backbone, given a value of the
wrong type and an out-of-range number, a set of broken transforms.json datasets, and issue 40's classes
(benchmarks/hostile_cases.py: crafted image headers, alpha, colour views, symbolic links, JSON encodings and depth,
intrinsics, synthetic-dataset keys, references, stage-2 sizes; benchmarks/hostile_tiff.py: TIFF views of every
compression, layout and sample format, and raw SEM series for ``arcsem-calibrate`` with vendor-tag variants), each run as the console script would (in-process,
for speed). Every case says what it must get: a clear error (exit 2, one ``error:`` line naming the file or key), a
warning, or a run. Prints one row per case and the tally: answered as expected, tracebacks, silent (accepted where
an error or a warning was due), unclear (an error without the names it must give), inputs changed, files written
outside the run folder and metrics.json files that are not strict JSON (all must be 0; exit 1 otherwise).

    .venv/bin/python benchmarks/hostile_inputs.py [--out FILE] [-k TEXT]

tests/test_hostile_inputs.py runs every case in CI.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import io
import json
import logging
import sys
import tempfile
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests.<module> imports
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from conftest import write_transforms_scene
from hostile_cases import CASES, Case
from hostile_files import json_edit


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
        "camera_model FISHEYE": lambda m: m.update(camera_model="FISHEYE"), "k4 nonzero (fisheye)": lambda m: m.update(k4=0.1),
        "split bogus": frame(split="val"), "mask missing": frame(mask_path="nomask.png"),
        "depth wrong shape": None, "aabb inverted": lambda m: m.update(aabb=[[1, 1, 1], [0, 0, 0]]),
        "aabb junk": lambda m: m.update(aabb="x"), "reference_sets junk": lambda m: m.update(reference_sets=[1]),
        "reference_sets unknown view": lambda m: m.update(reference_sets={"one": ["nope"]}),
        "ply missing": lambda m: m.update(ply_file_path="nope.ply"), "specimen_size -1": lambda m: m.update(specimen_size=-1),
        "duplicate frame": lambda m: m["frames"].append(dict(m["frames"][0])),
    }


def _hashes(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in root.rglob("*") if p.is_file() and not p.is_symlink() and "run" not in p.relative_to(root).parts}


def legacy_cases() -> list[Case]:
    """The first table (every config field given a wrong type and -7, broken transforms.json): all clear errors."""
    cases = [Case(name, "error", overrides=overrides) for name, overrides in config_cases()]
    for name, edit in dataset_cases().items():
        write = _depth_wrong_shape if edit is None else json_edit(edit)
        cases.append(Case(f"dataset: {name}", "error", write=write))
    return cases


def _depth_wrong_shape(root: Path) -> None:
    import numpy as np

    np.save(root / "d.npy", np.zeros((3, 3), np.float32))
    json_edit(lambda m: m["frames"][0].update(depth_path="d.npy"))(root)


@contextlib.contextmanager
def _address_space(gb: float | None):
    """RLIMIT_AS ``gb`` above the address space this process uses, for the block (None: unchanged)."""
    if gb is None:
        yield
        return
    import resource

    old = resource.getrlimit(resource.RLIMIT_AS)
    used = int(Path("/proc/self/status").read_text().split("VmSize:")[1].split()[0]) * 1024
    resource.setrlimit(resource.RLIMIT_AS, (used + int(gb * 1e9), old[1]))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, old)


class _Warnings(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def _strict_json(path: Path) -> bool:
    """Whether ``path`` (when it exists) parses as strict JSON (no NaN/Infinity), as JavaScript's JSON.parse would."""
    if not path.is_file():
        return True
    try:
        json.loads(path.read_text(), parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    except ValueError:
        return False
    return True


def _call(case: Case, folder: Path, overrides: list[str]) -> tuple[int | str, list[str], str, list[str]]:
    """Compose and run the case as the CLI does: ``(exit code or "traceback", error lines, stdout, warnings)``."""
    from hydra import compose, initialize_config_module

    from arcsem import app
    from arcsem.cli.errors import call_reporting_errors

    err, out, warned = io.StringIO(), io.StringIO(), _Warnings()
    logger = logging.getLogger("arcsem")
    logger.addHandler(warned)
    cwd = contextlib.chdir(folder) if case.in_case_dir else contextlib.nullcontext()
    try:
        with (contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), cwd,
              _address_space(case.address_space_gb), initialize_config_module("arcsem.conf", version_base="1.3")):
            code = call_reporting_errors(lambda: app.run(compose("config", overrides=overrides),
                                                         run_dir=folder / "run", overrides=overrides))
    except Exception:  # noqa: BLE001 (a traceback is what this audit looks for)
        return "traceback", [traceback.format_exc().strip().splitlines()[-1]], out.getvalue(), warned.lines
    finally:
        logger.removeHandler(warned)
    lines = [ln for ln in err.getvalue().splitlines() if ln.startswith("error:")]
    return (code if isinstance(code, int) else 0), lines, out.getvalue(), warned.lines


def _call_calibrate(case: Case, folder: Path, scene: Path) -> tuple[int | str, list[str], str, list[str]]:
    """Run ``arcsem-calibrate <scene>/raw --out <folder>/run <case.overrides>`` as the console script does: ``(exit
    code or "traceback", error lines, stdout, warnings)`` (Python warnings and the arcsem logger's)."""
    import warnings

    from arcsem.cli.calibrate import main

    err, out, warned = io.StringIO(), io.StringIO(), _Warnings()
    logger = logging.getLogger("arcsem")
    logger.addHandler(warned)
    try:
        with (contextlib.redirect_stderr(err), contextlib.redirect_stdout(out),
              warnings.catch_warnings(record=True) as caught):
            warnings.simplefilter("always")
            code = main([str(scene / "raw"), "--out", str(folder / "run"), *case.overrides])
    except SystemExit as exc:  # argparse
        code = exc.code if isinstance(exc.code, int) else 2
    except Exception:  # noqa: BLE001 (a traceback is what this audit looks for)
        return "traceback", [traceback.format_exc().strip().splitlines()[-1]], out.getvalue(), warned.lines
    finally:
        logger.removeHandler(warned)
    lines = [ln for ln in err.getvalue().splitlines() if ln.startswith("error:")]
    return code, lines, out.getvalue(), warned.lines + [str(w.message) for w in caught]


def judge(case: Case, code: int | str, lines: list[str], out: str, warned: list[str]) -> tuple[str, str]:
    """``(outcome, verdict)``: what happened (clear error, unclear error, traceback, warned, accepted) and whether it
    is the answer the case expects (``pass``, else ``traceback``, ``silent`` or ``unclear``)."""
    if code == "traceback":
        return "traceback", "traceback"
    if code != 0:
        outcome = "clear error" if code == 2 and len(lines) == 1 else "unclear error"
        if case.expect != "error":
            return outcome, "unclear"
        ok = outcome == "clear error" and all(n in lines[0] for n in case.needles)
        return outcome, "pass" if ok else "unclear"
    outcome = "warned" if warned else "accepted"
    if case.expect == "error":
        return outcome, "silent"
    if case.expect == "warning":
        return outcome, "pass" if any(all(n in w for n in case.needles) for w in warned) else "silent"
    text = out + "\n".join(warned)
    ok = all(n in text for n in case.needles) and not any(a in text for a in case.absent)
    return outcome, "pass" if ok else "unclear"


def run_case(tmp: Path, case: Case) -> dict:
    """Write the tiny scene, apply the case, run it (:func:`_call`) and judge it (:func:`judge`)."""
    folder = tmp / f"case{int(hashlib.sha1(case.name.encode()).hexdigest()[:8], 16)}"
    scene = write_transforms_scene(folder / "scene", n=4, w=32, h=24).parent
    written = case.write(scene) if case.write else None
    path_overrides = written if isinstance(written, list) else [f"dataset.path={scene}"]
    dataset = ["dataset=synthetic"] if case.dataset == "synthetic" else ["dataset=transforms", *path_overrides]
    before, entries = _hashes(folder), sorted(p.name for p in folder.iterdir())
    if case.tool == "calibrate":
        code, lines, out, warned = _call_calibrate(case, folder, scene)
    else:
        code, lines, out, warned = _call(case, folder, [*dataset, f"stage={case.stage}", *case.overrides])
    outcome, verdict = judge(case, code, lines, out, warned)
    return {"case": case.name, "expect": case.expect, "outcome": outcome, "verdict": verdict,
            "message": (lines or [w for w in warned if all(n in w for n in case.needles)] or [""])[0][:200],
            "inputs_changed": _hashes(folder) != before,
            "written_outside": sorted({p.name for p in folder.iterdir()} - set(entries) - {"run"}),
            "strict_metrics_json": _strict_json(folder / "run" / "metrics.json")}


def all_cases() -> list[Case]:
    """The first table and issue 40's cases (benchmarks/hostile_cases.py)."""
    return [*legacy_cases(), *CASES]


def tally(rows: list[dict]) -> dict[str, int]:
    """The counts the audit reports (every one but ``cases`` and ``pass`` must be 0)."""
    count = lambda v: sum(r["verdict"] == v for r in rows)
    return {"cases": len(rows), "pass": count("pass"), "tracebacks": count("traceback"), "silent": count("silent"),
            "unclear": count("unclear"), "inputs_changed": sum(r["inputs_changed"] for r in rows),
            "written_outside": sum(bool(r["written_outside"]) for r in rows),
            "metrics_json_not_strict": sum(not r["strict_metrics_json"] for r in rows)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="write the rows as JSON here")
    parser.add_argument("-k", default="", help="only the cases whose name holds this text")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [run_case(Path(tmp), c) for c in all_cases() if args.k in c.name]
    for r in rows:
        print(f"{r['verdict']:9s} {r['outcome']:13s} {r['case'][:46]:46s} {r['message'][:120]}")
    t = tally(rows)
    print(f"\n{t['cases']} cases: {t['pass']} answered as expected; {t['tracebacks']} tracebacks, {t['silent']} silent, "
          f"{t['unclear']} unclear; inputs changed: {t['inputs_changed']}, files written outside the run folder: "
          f"{t['written_outside']}, metrics.json not strict JSON: {t['metrics_json_not_strict']}")
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))
    return 0 if t["pass"] == t["cases"] and not (t["inputs_changed"] or t["written_outside"]) else 1


if __name__ == "__main__":
    sys.exit(main())
