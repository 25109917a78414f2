"""Per-study tables in the paper's layout (their files: :mod:`.formats`).

Rows follow the study's order; several runs of one row (seeds) are averaged and shown as
``mean ± std``. The best value of each column is bold (max for PSNR/SSIM, min for LPIPS and depth
error; among the rows of one scene and reference count where a study's rows join several keys). NaN
metrics print ``n/a`` and a note says why (e.g. LPIPS weights missing); rows whose jobs did not finish
print ``missing`` and the notes list those jobs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import pandas as pd

from ..errors import DataError
from .collect import STUDIES, Collection, MissingJob
from .paired import lower_is_better, pair, summary

__all__ = [
    "LAYOUTS",
    "PAPER_TABLE1",
    "Column",
    "Table",
    "build_table",
]


@dataclass(frozen=True)
class Column:
    group: str          # header above the column ("train views", "held-out", ...)
    label: str          # "PSNR"
    key: str            # flattened metrics key, e.g. "stage1.train.psnr"
    best: str | None    # "max" | "min" | None (no bold)
    digits: int
    text: bool = False  # a text column (e.g. the TCM/CCM features): the distinct values of the row's runs


def _ims(group: str, prefix: str) -> list[Column]:
    return [Column(group, "PSNR", f"{prefix}.psnr", "max", 2), Column(group, "SSIM", f"{prefix}.ssim", "max", 3),
            Column(group, "LPIPS", f"{prefix}.lpips", "min", 3)]


PAPER_TABLE1 = {  # ArCSEM Table 1 (training views, 3072x2048, real pollen data), from the paper's Table 1
    "plenoxels": (30.94, 0.855, 0.556), "gs3d": (37.50, 0.902, 0.461),
    "gs2d": (35.25, 0.867, 0.511), "gs2d_act": (36.32, 0.890, 0.489),
}
PAPER_COLUMNS = [Column("paper Table 1", n, f"paper.{n.lower()}", b, d)
                 for n, b, d in (("PSNR", "max", 2), ("SSIM", "max", 3), ("LPIPS", "min", 3))]

# "a|b": the first key a run has (the trainer writes held-out depth error as depth.test_mae[_pct])
DEPTH_PCT = "stage1.depth.test_mae_pct|stage1.depth.median_abs_pct"
DEPTH_ABS = "stage1.depth.test_mae|stage1.depth.median_abs"
CHAMFER = Column("mesh", "Chamfer %", "stage1.mesh.gt.chamfer_pct", "min", 2)  # built-in scene only

FEATURES = Column("TCM/CCM", "features", "features", None, 0, text=True)
CHOICE = Column("stage 2", "validated target", "stage2_choice", None, 0, text=True)


def _coverage(group: str, prefix: str) -> list[Column]:
    """PSNR inside / outside the pseudo-colour coverage (arcsem.colorize.coverage) and the covered share."""
    return [Column(group, "PSNR in cov.", f"{prefix}.psnr_covered", "max", 2),
            Column(group, "PSNR out cov.", f"{prefix}.psnr_uncovered", "max", 2),
            Column(group, "coverage", f"{prefix}.coverage", None, 3)]


COLOUR = (_ims("non-ref. train views", "stage2.train_nonref") + _ims("held-out", "stage2.test")
          + _coverage("held-out", "stage2.test") + [FEATURES, CHOICE])
TABLE1_PROTOCOL = "train views: own ACT, observed images (Table 1 protocol)"
HELD_OUT = "held-out"
LAYOUTS: dict[str, list[Column]] = {
    "grayscale_comparison": _ims(TABLE1_PROTOCOL, "stage1.train_paper") + _ims(HELD_OUT, "stage1.test") + [
        Column("depth (held-out)", "err. %", DEPTH_PCT, "min", 2),
        Column("depth (held-out)", "err.", DEPTH_ABS, "min", 4), CHAMFER] + PAPER_COLUMNS,
    "colorization_ablation": COLOUR,
    "reference_count": COLOUR,
    "feature_comparison": COLOUR,
    "colorization_benchmark": COLOUR,
    "runs": _ims("grey train (Table 1 protocol)", "stage1.train_paper") + _ims("grey held-out", "stage1.test") + [
        Column("depth", "err. %", DEPTH_PCT, "min", 2), CHAMFER]
    + _ims("colour non-ref.", "stage2.train_nonref") + _ims("colour held-out", "stage2.test")
    + _coverage("colour held-out", "stage2.test") + [FEATURES, CHOICE],
}
ROW_HEADER = {"grayscale_comparison": "Model", "colorization_ablation": "Variant",
              "reference_count": "References", "feature_comparison": "References, features",
              "colorization_benchmark": "Scene, references, stage 2", "runs": "Run"}


@dataclass
class Table:
    """A study's table: formatted cells (with bold flags), the numbers and the notes."""

    study: str
    columns: list[Column]
    labels: list[str]
    cells: list[list[tuple[str, bool]]]   # [row][col] -> (text, bold)
    numbers: pd.DataFrame                 # CSV content
    notes: list[str]


def _fmt(mean: float, std: float, n: int, digits: int) -> str:
    if n == 0 or math.isnan(mean):
        return "n/a"
    text = f"{mean:.{digits}f}"
    return f"{text} ± {std:.{digits}f}" if n > 1 and not math.isnan(std) else text


def _summary(df: pd.DataFrame, study: str, columns: list[Column], missing: list[MissingJob]) -> pd.DataFrame:
    """One row per study row (in order): ``label``, ``n``, ``status`` and ``<key>``/``<key>.std``."""
    spec = STUDIES[study]
    present = set(df["row"].dropna()) | {m.row for m in missing if m.row}
    order = [r for r in spec.rows if r in present] + sorted(present - set(spec.rows))
    recs = []
    for row in order:
        sub = df[df["row"] == row]
        n_miss = sum(1 for m in missing if m.row == row)
        rec = {"row": row, "label": spec.rows.get(row, row), "n": len(sub),
               "status": "ok" if not n_miss else ("missing" if sub.empty else f"{n_miss} job(s) missing")}
        for c in columns:
            if c.text:
                vals = _per_run(sub, c.key).dropna().astype(str)
                rec[c.key] = ", ".join(sorted(set(vals))) or "n/a"
                continue
            if c.key.startswith("paper."):
                vals = PAPER_TABLE1.get(row)
                rec[c.key] = math.nan if vals is None else vals[["psnr", "ssim", "lpips"].index(c.key[6:])]
                continue
            vals = pd.to_numeric(sub[c.key], errors="coerce") if c.key in sub else pd.Series(dtype=float)
            rec[c.key] = float(vals.mean()) if vals.notna().any() else math.nan
            rec[f"{c.key}.std"] = float(vals.std(ddof=1)) if vals.notna().sum() > 1 else math.nan
        recs.append(rec)
    return pd.DataFrame.from_records(recs)


def _recorded(df: pd.DataFrame, suffix: str) -> list[str]:
    """The columns that hold what runs recorded as ``suffix``: ``suffix`` itself first, then ``*.suffix``
    (``stage2.features``), not the config key an override sets (``colorize.features=vgg16`` is the request;
    the run records what it got: ``vgg16-random``)."""
    cols = [c for c in df.columns if c.endswith("." + suffix) and not c.startswith("colorize.")]
    return ([suffix] if suffix in df.columns else []) + cols


def _distinct(df: pd.DataFrame, suffix: str) -> list[str]:
    return sorted({str(v) for c in _recorded(df, suffix) for v in df[c].dropna()})


def _per_run(df: pd.DataFrame, suffix: str) -> pd.Series:
    """The first non-null recorded value per run among the columns named ``suffix`` or ``*.suffix``."""
    cols = _recorded(df, suffix)
    return df[cols].bfill(axis=1).iloc[:, 0] if cols else pd.Series([], dtype=object)


def no_paths(text: str) -> str:
    """``text`` with machine paths cut to what they name: the torch hub folder by that name, other
    folders and files by their last part (``/root/.cache/torch/hub/checkpoints`` -> ``the torch hub
    cache``, ``/x/y/alexnet.pth`` -> ``alexnet.pth``); URLs are kept."""
    import re

    def short(m: re.Match) -> str:
        path = m.group(0)
        return "the torch hub cache" if path.rstrip("/").endswith("hub/checkpoints") else Path(path).name
    return re.sub(r"(?<![\w:/.])(?:~|/)[^\s;,()'\"]*", short, text)


CONVENTION_NOTES = {
    "3dgs": "the 3DGS/2DGS evaluation scripts' convention, which the paper used: renders scored as 8-bit images, "
            "SSIM with an 11x11 Gaussian window (sigma 1.5) over zero-padded images averaged over every pixel, "
            "LPIPS with VGG16",
    "skimage": "renders scored as floats, scikit-image SSIM (Gaussian window sigma 1.5, reflected borders, the "
               "outer 5 pixels left out), LPIPS with AlexNet",
}


def _convention_notes(names: list[str]) -> list[str]:
    """What the recorded metric conventions (``*.metrics_convention.name``) mean; older runs recorded none."""
    if not names:
        return [("metrics: convention not recorded (runs older than the convention setting: scikit-image SSIM, "
                 "LPIPS with AlexNet, float renders).")]
    return [f"metrics ({n}): {CONVENTION_NOTES.get(n, 'unknown convention')}." for n in names]


def _lpips_notes(values: list[str], any_nan: bool) -> list[str]:
    """Notes on the LPIPS weights from the recorded ``lpips_weights`` values ("; "-joined lists allowed).

    A value is a checkpoint path or name (weights found) or ``missing: <reason>`` / ``skipped``.
    Missing weights get the command that fetches them (``python -m arcsem.weights``).
    """
    from ..weights import FETCH_COMMAND

    parts = sorted({p.strip() for v in values for p in v.split(";") if p.strip()})
    is_bad = lambda p: p.lower().startswith(("missing", "skipped", "random"))
    bad = [no_paths(p) for p in parts if is_bad(p)]
    good = sorted({Path(p).name for p in parts if not is_bad(p)})
    notes = []
    if bad and all(b.lower() == "skipped" for b in bad):
        notes.append("LPIPS: n/a: not computed (the run set eval.lpips=false).")
    elif bad or (any_nan and not parts):
        notes.append("LPIPS: n/a: weights missing (" + "; ".join(bad or ["not recorded"]) + "). To get LPIPS, "
                     f"fetch the ImageNet weights on a machine with network ({FETCH_COMMAND}) and run the job "
                     "again: a number made with random weights is never shown.")
    if good:
        nets = sorted({"VGG16" if g.startswith("vgg") else "AlexNet" for g in good})
        notes.append(f"LPIPS: {' and '.join(nets)} v0.1, ImageNet weights " + ", ".join(good) + ".")
    elif not (bad or any_nan):
        notes.append("LPIPS weights: not recorded.")
    return notes


def _notes(study: str, df: pd.DataFrame, nums: pd.DataFrame, columns: list[Column],
           missing: list[MissingJob]) -> list[str]:
    notes = []
    if study == "grayscale_comparison":
        notes.append("two protocols: Table 1 protocol: the training views, each rendered with its own ACT and "
                     "scored against the observed (noisy, exposure-drifted) image, as the paper's Table 1; held-out: "
                     "the test views, rendered with the mean ACT and scored against the noise-free images where the "
                     "dataset has them (the built-in scenes), else against the observed ones; depth err.: median "
                     "|depth - GT| over held-out views inside the mask (% of the specimen's diameter where the dataset "
                     "states it, e.g. the synthetic grain's 2 units, else of the bounding-box diagonal; and in scene "
                     "units).")
        notes.append("paper Table 1: ArCSEM's published numbers on real SEM data (32 views, 3072x2048); "
                     "not the same scene as ours.")
    elif study == "runs":
        notes.append("runs of no study (e.g. the demo), one row per run folder; grey metrics on training "
                     "views (the paper's Table 1 protocol: own ACT, observed images) and held-out views (mean ACT), "
                     "colour metrics against ground-truth colour.")
    else:
        notes.append("non-ref. train views: training views that are not colour references; held-out: test "
                     "views; metrics against ground-truth colour.")
    if any(c.key == CHAMFER.key for c in columns):
        notes.append("mesh Chamfer %: the TSDF mesh (mesh.ply) against the built-in grain's true surface: mean of "
                     "accuracy (mesh to surface) and completeness (surface seen by a training view to mesh), % of "
                     "the grain's diameter.")
    ran = nums[nums["status"] != "missing"] if len(nums) else nums
    lp_nan = any(math.isnan(v) for c in columns if c.label == "LPIPS" and not c.key.startswith("paper.")
                 for v in ran.get(c.key, []))
    if len(df):
        notes += _convention_notes(_distinct(df, "metrics_convention.name"))
        notes += _lpips_notes(_distinct(df, "lpips_weights"), lp_nan)
    feats = _distinct(df, "features")
    if study != "grayscale_comparison" and (feats or study != "runs"):
        notes += _feature_notes(df, feats)
        if any(c.key.endswith("psnr_uncovered") for c in columns):
            notes.append("PSNR in / out cov.: held-out colour PSNR pooled over the specimen pixels that pseudo-colours "
                         "reach (a reference point within the search radius) and over the rest, which only the "
                         "surface spread, the grey prior, TCM, CCM and the model's own interpolation colour; "
                         "coverage: the covered share.")
    if any(c.key == CHOICE.key for c in columns):
        notes.append("validated target: what stage 2 trained towards, chosen per run by holding each artist reference "
                     "out in turn (colorize.validate=auto; with one reference, each half of it): the pseudo-colours "
                     "spread over the surface, carried with the SEM shading, completed by the grey prior (the "
                     "references' colour at a pixel's grey), or the pseudo-colours alone; in brackets the chosen "
                     "target's gain over the pseudo-colours alone on what was held out; +TCM/+CCM: the guided losses "
                     "that trained (kept by the validation and by the match check against the pseudo-colours). "
                     "'as configured': no validation (validate=off).")
    seeds = sorted({str(s) for s in df["seed"].dropna()}) if "seed" in df else []
    if seeds:
        notes.append(f"seeds: {', '.join(seeds)}; several runs per row are shown as mean ± std.")
    notes += _paired_notes(df, study, columns)
    for m in missing:
        where = "/".join(Path(m.job_dir).parts[-2:]) if m.job_dir else f"{Path(m.sweep_dir).name} (job never started)"
        why = f" ({m.reason})" if m.reason else ""
        notes.append(f"missing job: {' '.join(m.overrides)} -- {where}{why}")
    return notes


def _feature_notes(df: pd.DataFrame, feats: list[str]) -> list[str]:
    """What TCM/CCM matched with: the recorded ``features`` (``vgg16-imagenet``, ``vgg16-random``, ``daisy``,
    ``learned``, ``unused``; older runs: ``imagenet`` / ``random``)."""
    notes = []
    per_run = _per_run(df, "features")
    random = per_run.astype(str).str.contains("random")
    used = per_run.notna() & (per_run.astype(str) != "unused")
    if bool(random.any()):
        n_random, n_used = int(random.sum()), int(used.sum())
        which = "every run that uses them" if n_random == n_used else f"{n_random} of the {n_used} runs that use them"
        notes.append(f"VGG features: RANDOM weights in {which} (ImageNet weights unavailable): TCM/CCM "
                     "numbers are not the standard ones.")
    notes.append("TCM/CCM features: " + (", ".join(feats) if feats else "not recorded") + ".")
    return notes


def _paired_notes(df: pd.DataFrame, study: str, columns: list[Column]) -> list[str]:
    """Held-out PSNR of each row minus the study's own method, paired by seed, where >= 2 seeds pair up.

    The note gives the differences' mean, its 95 % t-interval (does the row differ beyond run-to-run
    noise?) and the seeds the row won.
    """
    spec = STUDIES[study]
    keys = [(c.key, c.label if c.group == HELD_OUT else f"{c.label} (Table 1 protocol)") for c in columns
            if (c.group == HELD_OUT and c.label in ("PSNR", "PSNR out cov.")) or (c.group == TABLE1_PROTOCOL
                                                                                 and c.label == "PSNR")]
    if not keys or "seed" not in df:
        return []
    present = set(df["row"].dropna())
    rows = [r for r in spec.rows if r in present] + sorted(present - set(spec.rows))
    if spec.ours is not None and spec.ours in present:
        against = {r: spec.ours for r in rows if r != spec.ours}
        whose = f"{spec.rows[spec.ours]}'s"
    elif spec.ours_last is not None:  # each row against its own scene and reference count's method
        against = {r: f"{r.rsplit('/', 1)[0]}/{spec.ours_last}" for r in rows if "/" in r
                   and not r.endswith(f"/{spec.ours_last}")}
        against = {r: a for r, a in against.items() if a in present}
        name = spec.rows.get(next(iter(against.values()), ""), "").rsplit(", ", 1)[-1]  # "grain, 1, default"
        whose = f"the {name} of the same {spec.group_name or 'group'}"
    else:
        return []
    return [n for key, label in keys if key in df for n in _paired_note(df, spec, key, label, against, whose)]


def _paired_note(df: pd.DataFrame, spec, key: str, label: str, against: dict[str, str], whose: str) -> list[str]:
    """One note: ``label`` (a held-out PSNR column) of each row minus its ``against`` row, paired by seed."""
    parts = []
    for row, ours in against.items():
        try:
            table, _ = pair(df, ours, row, key)
        except DataError:  # several runs of one row and seed (e.g. a rerun): no unique pairing
            parts.append(f"{spec.rows.get(row, row)}: not paired (several runs of one seed)")
            continue
        if len(table) < 2:
            continue
        s = summary(table["delta"], lower_is_better(key))
        parts.append(f"{spec.rows.get(row, row)} {s['mean']:+.2f} dB [{s['ci_low']:+.2f}, {s['ci_high']:+.2f}], "
                     f"better at {s['b_wins']}/{s['n']} seeds")
    if not parts:
        return []
    what = "held-out PSNR" if label == "PSNR" else (label if "Table 1" in label else f"held-out {label}")
    return [f"{what} minus {whose}, paired by seed (mean, 95 % t-interval): " + "; ".join(parts) + "."]


def _group(study: str, row: str) -> str:
    """The rows a row's values are bolded among: in a study whose rows join several keys (``also``: a scene and a
    reference count, then the stage-2 variant or extractor) the rows that differ only in the last key, so that the
    bold says which variant is best for that scene and count, not which scene is easiest; else every row."""
    return str(row).rsplit("/", 1)[0] if STUDIES[study].also and "/" in str(row) else ""


def build_table(coll: Collection, study: str) -> Table:
    """The table of ``study`` from a :class:`Collection` (rows with neither runs nor missing jobs omitted)."""
    df = coll.runs[coll.runs["study"] == study] if len(coll.runs) else coll.runs
    missing = [m for m in coll.missing if m.study == study]
    columns = []
    for c in LAYOUTS[study]:  # columns no finished run has are left out (all kept when none finished)
        alts = c.key.split("|")
        key = next((k for k in alts if k.startswith("paper.") or k in df.columns
                    or (c.text and any(str(x).endswith("." + k) for x in df.columns))), None if len(df) else alts[0])
        if key is not None:
            columns.append(replace(c, key=key))
    nums = _summary(df, study, columns, missing)
    groups = nums["row"].map(lambda row: _group(study, row)) if len(nums) else pd.Series(dtype=str)
    best = {}
    for c in [c for c in columns if not c.text]:
        for g in set(groups):
            vals = nums.loc[groups == g, c.key].dropna() if len(nums) else pd.Series(dtype=float)
            if c.best and len(vals) > 1:  # a lone value is not "best" of anything
                best[g, c.key] = round(vals.max() if c.best == "max" else vals.min(), c.digits)
    cells = []
    for i, r in nums.iterrows():
        row = []
        for c in columns:
            if r["status"] == "missing" and not c.key.startswith("paper."):
                row.append(("missing", False))
                continue
            if c.text:
                row.append((str(r[c.key]), False))
                continue
            mean, std = r[c.key], r.get(f"{c.key}.std", math.nan)
            n = 1 if c.key.startswith("paper.") else int(r["n"])
            top = best.get((groups[i], c.key))
            bold = top is not None and not math.isnan(mean) and round(mean, c.digits) == top
            row.append((_fmt(mean, std, n, c.digits), bold))
        cells.append(row)
    notes = _notes(study, df, nums, columns, missing)
    return Table(study, columns, list(nums["label"]) if len(nums) else [], cells, nums, notes)
