"""Find runs under folders, flatten their ``metrics.json`` into a DataFrame, list missing sweep jobs.

A *run* is a folder with ``metrics.json`` (written by ``arcsem`` at the end of a job). A *multirun*
is a Hydra sweep folder with ``multirun.yaml``; its expected jobs are expanded from the sweep's
overrides and compared with the jobs that finished, so an interrupted sweep yields ``missing``
rows instead of an error.

Row columns: ``run_dir``, ``study``, ``row`` (the study's row key, e.g. ``gs2d_act``), ``seed``,
``git``, one column per override (``variant``, ``colorize.references``, ...) and one per metric,
flattened with dots (``stage1.train.psnr``).
"""
from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from hydra.errors import OverrideParseException

from ..configs import EXTRACTORS
from ..errors import DataError

__all__ = [
    "OTHER",
    "STUDIES",
    "Collection",
    "MissingJob",
    "Study",
    "collect",
    "expected_jobs",
    "find_runs",
    "flatten",
    "parse_overrides",
]


@dataclass(frozen=True)
class Study:
    """A study: which override picks its rows, their order and printed labels."""

    name: str
    key: str                      # override key whose value is the row (e.g. "variant")
    rows: dict[str, str]          # row value -> label, in table order
    ours: str | None = None       # the paper's method: other rows are compared with it, paired by seed
    also: tuple[str, ...] = ()    # further keys whose values join the row: "one/daisy" (key/also...)
    ours_last: str | None = None  # the method by the last key's value: each row is compared with the row of its
    # group (the same values of the other keys) that has it ("synthetic/one/pseudo_only" with "synthetic/one/full")
    group_name: str = ""          # what a group is, in the notes ("scene and reference count")


_REFERENCES = {"one": "1", "two": "2", "three": "3", "four": "4", "five": "5"}
_COLOUR_SCENES = (("synthetic", "grain"), ("diatom", "diatom"), ("parts", "parts"), ("public_fox", "fox"),
                  ("public_chair", "chair (held out)"))  # colorization_benchmark's datasets; the held-out one last
_EXTRACTORS = (*EXTRACTORS, "auto")  # colorize.features, in table order


STUDIES: dict[str, Study] = {
    s.name: s for s in (
        Study("grayscale_comparison", "variant",
              {"plenoxels": "Plenoxels", "gs3d": "3DGS", "gs2d": "2DGS", "gs2d_act": "2DGS + ACT"}, "gs2d_act"),
        Study("colorization_ablation", "ablation",
              {"full": "full", "no_tcm": "w/o TCM", "no_ccm": "w/o CCM", "no_act": "w/o ACT",
               "no_all": "w/o all"}, "full"),
        Study("feature_comparison", "colorize.references",  # before reference_count: it has both keys
              {f"{r}/{f}": f"{n}, {f}" for r, n in _REFERENCES.items() for f in _EXTRACTORS}, also=("colorize.features",)),
        Study("colorization_benchmark", "dataset",  # before reference_count: it has its key
              {f"{d}/{r}/{a}": f"{dn}, {n}, {an}" for d, dn in _COLOUR_SCENES
               for r, n in (("one", "1"), ("three", "3"), ("five", "5"))
               for a, an in (("full", "default"), ("pseudo_only", "pseudo-colours"))},
              also=("colorize.references", "ablation"), ours_last="full", group_name="scene and reference count"),
        Study("reference_count", "colorize.references",
              {"five": "5", "four": "4", "three": "3", "two": "2", "one": "1"}, "five"),
        Study("runs", "", {}),  # every run of no known study (demo, single runs): one row per run folder
    )
}
OTHER = "runs"


@dataclass
class MissingJob:
    """A job of a sweep without ``metrics.json`` (never started, crashed or still running)."""

    sweep_dir: str
    overrides: list[str]
    job_dir: str | None = None    # None when the job folder was never created
    study: str | None = None
    row: str | None = None
    reason: str = ""              # why it counts as missing, when not simply "no metrics.json"


@dataclass
class Collection:
    """Everything found: one DataFrame row per finished run, plus the missing jobs."""

    runs: pd.DataFrame
    missing: list[MissingJob] = field(default_factory=list)


def parse_overrides(items: list[str] | None) -> dict[str, str]:
    """``["+variant=gs2d", "seed=1"]`` -> ``{"variant": "gs2d", "seed": "1"}`` (``+``/``~`` dropped)."""
    out: dict[str, str] = {}
    for item in items or []:
        if "=" not in item:
            continue
        key, value = item.split("=", 1)
        key = key.lstrip("+~")
        out[key] = value
    return out


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts -> ``{"a.b.c": value}``; lists stay values; ``None`` -> NaN for numbers."""
    out: dict[str, Any] = {}
    if isinstance(data, dict):
        for k, v in data.items():
            out.update(flatten(v, f"{prefix}{k}."))
        return out
    out[prefix[:-1]] = math.nan if data is None else data
    return out


def _read_yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        return None
    except yaml.YAMLError as err:
        raise DataError(f"{path}: not valid YAML ({err.__class__.__name__})") from None


def _job_overrides(run: Path, metrics: dict | None) -> list[str]:
    """Overrides of a run: ``metrics.json`` first, then ``.hydra/overrides.yaml``."""
    if metrics and isinstance(metrics.get("overrides"), list):
        return [str(o) for o in metrics["overrides"]]
    return [str(o) for o in (_read_yaml(run / ".hydra" / "overrides.yaml") or [])]


def _choices(run: Path) -> dict[str, str]:
    hydra_cfg = _read_yaml(run / ".hydra" / "hydra.yaml") or {}
    return dict(((hydra_cfg.get("hydra") or {}).get("runtime") or {}).get("choices") or {})


def identify(overrides: dict[str, str], choices: dict[str, str], config: dict | None) -> tuple:
    """``(study, row)`` from overrides, Hydra's recorded choices or ``config.study``; None if unknown."""
    config = config or {}
    study_cfg = config.get("study") if isinstance(config.get("study"), dict) else {}
    name = (overrides.get("experiment") or choices.get("experiment") or study_cfg.get("name"))
    if name not in STUDIES or name == OTHER:  # infer from the row keys present
        name = next((s.name for s in STUDIES.values() if s.key and all(
            k in overrides or k in choices for k in (s.key, *s.also))), None)
    study = STUDIES.get(name)
    if study is None:
        return OTHER, None
    parts = [_row_part(k, overrides, choices, config) for k in (study.key, *study.also)]
    if parts[0] is None:
        parts[0] = study_cfg.get("row")
    if any(p is None for p in parts):
        return name, None
    return name, "/".join(str(p) for p in parts)


def _row_part(key: str, overrides: dict[str, str], choices: dict[str, str], config: dict) -> Any:
    """The value of ``key`` for a run: its override, Hydra's choice, or (``colorize.*``) the config's value."""
    value = overrides.get(key) or choices.get(key)
    if value is None and key.startswith("colorize."):  # e.g. colorize.references set by the experiment
        value = (config.get("colorize") or {}).get(key.split(".", 1)[1])
    return value


BACKBONE_LABELS = {"gs2d": "2DGS", "gs3d": "3DGS", "plenoxels": "Plenoxels"}


def method_label(run: Path, metrics: dict, config: dict, overrides: dict[str, str], choices: dict[str, str]) -> str:
    """A row name for a run of no study: the method (``2DGS + ACT``), the experiment it ran
    (``demo``) and the dataset when it is not the built-in scene (folder name, never a full path);
    runs that recorded no backbone keep their folder's last two parts."""
    backbone = metrics.get("backbone") or (config.get("backbone") or {}).get("name")
    if not backbone:
        return "/".join(run.parts[-2:])
    label = BACKBONE_LABELS.get(str(backbone), str(backbone))
    if ((config.get("act") or {}).get("enabled")):
        label += " + ACT"
    extra = [overrides.get("experiment") or choices.get("experiment")]
    ds = config.get("dataset") or {}
    if ds.get("kind") not in (None, "synthetic"):
        extra.append(Path(str(ds.get("path") or ds.get("kind"))).name)
    extra = [str(e) for e in extra if e]
    return f"{label} ({', '.join(extra)})" if extra else label


def read_run(run: Path) -> dict[str, Any]:
    """One flattened record of the run folder ``run`` (which must hold ``metrics.json``)."""
    try:
        metrics = json.loads((run / "metrics.json").read_text())
    except json.JSONDecodeError as err:
        raise DataError(f"{run / 'metrics.json'}: not valid JSON ({err.msg}, line {err.lineno})") from None
    config = _read_yaml(run / "config.yaml") or _read_yaml(run / ".hydra" / "config.yaml") or {}
    ovr = parse_overrides(_job_overrides(run, metrics))
    choices = _choices(run)
    study, row = identify(ovr, choices, config)
    row = row if study != OTHER else method_label(run, metrics, config, ovr, choices)
    rec: dict[str, Any] = {"run_dir": str(run), "study": study, "row": row,
                           "seed": metrics.get("seed", config.get("seed")),
                           "git": metrics.get("git", metrics.get("git_revision"))}
    rec.update(ovr)
    skip = {"overrides", "seed", "git", "git_revision"}
    rec.update(flatten({k: v for k, v in metrics.items() if k not in skip}))
    stages = metrics.get("stages") if isinstance(metrics.get("stages"), dict) else {}
    for stage, alias in (("gray", "stage1"), ("color", "stage2")):  # results not wrapped in stage1/2
        if alias not in metrics and isinstance(stages.get(stage), dict):
            rec.update(flatten(stages[stage].get(alias, stages[stage]), f"{alias}."))
    if any(k.startswith("stage2.") for k in rec):
        rec["stage2_choice"] = stage2_choice(rec)
    return rec


def stage2_choice(rec: dict[str, Any]) -> str:
    """What stage 2 trained towards, from a run's flattened record: the pseudo-colour target chosen by the
    leave-one-reference-out validation (``stage2.validation``: surface spread, shading, grey prior, or none), with the
    chosen target's held-out error beside the pseudo-colours' alone, ``as configured`` when the run did not validate
    (``colorize.validate=off``, or a run from before one reference validated); then the guided losses that trained (``stage2.losses``: what the
    validation and the guard's match check kept; older runs: the validation's keep)."""
    v = {k.removeprefix("stage2.validation."): x for k, x in rec.items() if k.startswith("stage2.validation.")}
    trained = rec.get("stage2.losses")
    kept = [n.upper() for n in ("tcm", "ccm") if (n in trained if isinstance(trained, list) else v.get(f"{n}.keep"))]
    if "surface" not in v:
        return "as configured" + "".join(f" +{k}" for k in kept)
    parts = [n for n, on in (("surface", v["surface"] != "off"), ("shading", v.get("shading") != "off"),
                             ("prior", v.get("prior", "off") != "off")) if on]
    target = "+".join(parts) or "pseudo-colours"
    if v.get("references") == 1:  # one reference: its halves chose the surface spread and the prior
        key, none = f"{v['surface']}/{v['prior']}", "off/off"
    elif "prior" in v:
        key, none = f"{v['surface']}/{v.get('shading')}/{v['prior']}", "off/off/off"
    else:  # runs from before the prior
        key, none = f"{v['surface']}/{v.get('shading')}", "off/off"
    chosen, plain = v.get(f"target_mse.{key}"), v.get(f"target_mse.{none}")
    err = ""
    if isinstance(chosen, (int, float)) and isinstance(plain, (int, float)) and chosen > 0 and plain > 0:
        import math

        err = f" ({10 * math.log10(plain / chosen):+.1f} dB)"
    return f"{target}{err}" + "".join(f" +{k}" for k in kept)


def find_runs(paths: list[Path], exclude: Path | None = None) -> list[Path]:
    """Every folder under ``paths`` holding ``metrics.json`` (sorted; ``exclude`` skipped)."""
    runs = set()
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise DataError(f"{p}: no such run or multirun folder")
        for m in p.rglob("metrics.json"):
            if exclude is not None and exclude.resolve() in m.resolve().parents:
                continue
            runs.add(m.parent)
    return sorted(runs, key=lambda r: (str(r.parent), _numeric(r.name)))


def _numeric(name: str) -> tuple:
    return (0, int(name), "") if name.isdigit() else (1, 0, name)


def expected_jobs(multirun_yaml: Path) -> list[list[str]]:
    """The override lists of every job of a sweep, expanded as Hydra's basic sweeper does."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    cfg = _read_yaml(multirun_yaml) or {}
    hydra_cfg = cfg.get("hydra") or {}
    task = list(((hydra_cfg.get("overrides") or {}).get("task")) or [])
    params = ((hydra_cfg.get("sweeper") or {}).get("params")) or {}
    items = [f"{k}={v}" for k, v in params.items()] + task
    parsed = OverridesParser.create().parse_overrides(items)
    axes: dict[str, list[str]] = {}
    for ov in parsed:  # later entries (command line) win over sweeper params, as in Hydra
        key = ov.get_key_element()
        axes[key] = ([f"{key}={v}" for v in ov.sweep_string_iterator()] if ov.is_sweep_override()
                     else [f"{key}={ov.get_value_element_as_str()}"])
    return [list(combo) for combo in itertools.product(*axes.values())]


def _missing_in_sweep(sweep: Path, done_dirs: set[str]) -> list[MissingJob]:
    """Jobs of the sweep at ``sweep`` that have no ``metrics.json``."""
    present: dict[frozenset, Path] = {}
    lists: dict[Path, list[str]] = {}
    for sub in sorted(sweep.iterdir()):
        ovr = _read_yaml(sub / ".hydra" / "overrides.yaml") if sub.is_dir() else None
        if ovr is not None:
            present[frozenset(parse_overrides(ovr).items())] = sub
            lists[sub] = [str(o) for o in ovr]
    try:
        wanted = expected_jobs(sweep / "multirun.yaml")
    except (OverrideParseException, DataError, AttributeError, TypeError, ValueError):  # an unparsable sweep: fall back to the job folders alone
        wanted = list(lists.values())
    missing = []
    for job in wanted:
        key = frozenset(parse_overrides(job).items())
        sub = present.get(key)
        if sub is not None and str(sub) in done_dirs:
            continue
        study, row = identify(dict(key), {}, {})
        ovr = list(job) if sub is None else lists[sub]
        if study == OTHER:
            row = "/".join(Path(sub).parts[-2:]) if sub is not None else " ".join(ovr)
        missing.append(MissingJob(str(sweep), ovr, None if sub is None else str(sub), study, row))
    return missing


def collect(paths: list[str | Path], exclude: Path | None = None) -> Collection:
    """Collect every run under ``paths`` and the missing jobs of every sweep folder there."""
    paths = [Path(p) for p in paths]
    records, broken = [], {}
    for run in find_runs(paths, exclude):
        try:
            records.append(read_run(run))
        except DataError as err:  # e.g. a truncated metrics.json: reported as missing, not fatal
            broken[str(run)] = str(err)
    done = {r["run_dir"] for r in records}
    sweeps = sorted({m.parent for p in paths for m in p.rglob("multirun.yaml")})
    missing = [m for s in sweeps for m in _missing_in_sweep(s, done)]
    for m in missing:
        m.reason = broken.pop(m.job_dir, "") if m.job_dir else ""
    missing += [MissingJob(str(Path(r).parent), [], r, OTHER, "/".join(Path(r).parts[-2:]), why)
                for r, why in broken.items()]  # broken runs outside any sweep
    df = pd.DataFrame.from_records(records) if records else pd.DataFrame(
        columns=["run_dir", "study", "row", "seed", "git"])
    return Collection(df, missing)
