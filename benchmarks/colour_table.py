"""The colour comparison's table: held-out colour PSNR (whole, masked, inside and outside the pseudo-colour
coverage) of every stage-2 run folder under a directory, the reference views' own PSNR, the target the
validation chose and the guided losses that trained.

    .venv/bin/python benchmarks/colour_table.py DIR [DIR ...]     # run folders DIR/<scene>_<refs>_<variant>/
    .venv/bin/python benchmarks/colour_table.py --pairs DIR        # default against pseudo_only, per scene and refs
    .venv/bin/python benchmarks/colour_table.py --seeds DIR [DIR ...]  # the same pairs per seed (_s<k> folders;
                                                                   # a later DIR's run replaces an earlier one's)
    .venv/bin/python benchmarks/colour_table.py --ablations DIR [DIR ...]  # the default against every other variant
                                                                   # per seed, outside the coverage, and its spread
    .venv/bin/python benchmarks/colour_table.py --outside DIR [DIR ...]  # issue 38's second line: the outside-coverage
                                                                   # gain by scene and reference count, averaged
                                                                   # and pooled over the pixels
    .venv/bin/python benchmarks/colour_table.py --versus OLD NEW   # the same runs of two sweeps (two commits), paired

A DIR may also be a Hydra multirun folder (``arcsem experiment=colorization_benchmark``): its numbered runs are named
``<dataset>_<references>_<variant>[_s<seed>]`` from their overrides (``ablation=full`` is the ``default``; with an
addition switched off, ``colorize.prior=off`` and the others of :data:`SWITCHES`, the variant is ``no_prior``, ...).
"""
from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path


def row(run: Path, name: str | None = None) -> str | None:
    m = json.loads((run / "metrics.json").read_text())
    s2 = m.get("stage2")
    if not s2:
        return f"| {name or run.name} | failed: {m.get('error')} |"
    t, v = s2["test"], s2.get("validation") or {}
    trained = s2.get("losses") or []  # the guided losses that trained: kept by the validation and the match check
    chose = (f"{v['surface']}/{v['shading']}" + (f"/{v['prior']}" if "prior" in v else "") + ", " if v else "") + \
        f"TCM {'on' if 'tcm' in trained else 'off'}, CCM {'on' if 'ccm' in trained else 'off'}"
    f = lambda d, k: f"{d[k]:.2f}" if d.get(k) is not None else "-"  # no masks: no masked PSNR
    return (f"| {name or run.name} | {f(t, 'psnr')} | {f(t, 'psnr_masked')} | {f(t, 'psnr_covered')} | "
            f"{f(t, 'psnr_uncovered')} | {t.get('uncovered_px', '-')} | {f(s2.get('train_ref', {}), 'psnr')} | "
            f"{chose} | {m.get('git_revision', '')[:7]} |")


def pairs(d: str) -> None:
    """One row per ``<scene>_<refs>`` with both a ``default`` and a ``pseudo_only`` run (seed 0 only)."""
    def test(run: Path) -> dict:
        return json.loads((run / "metrics.json").read_text())["stage2"]["test"]

    f = lambda x: "-" if x is None else f"{x:.2f}"
    g = lambda a, b: "-" if a is None or b is None else f"{a - b:+.2f}"
    print("| scene, references | default | pseudo-colours | gain (whole / masked) | inside cov. d / p | "
          "outside cov. d / p |")
    print("|---|---:|---:|---:|---:|---:|")
    for run in sorted(Path(d).glob("*_default/metrics.json")):
        stem = run.parent.name.removesuffix("_default")
        base = Path(d) / f"{stem}_pseudo_only"
        if not (base / "metrics.json").is_file():
            continue
        a, b = test(run.parent), test(base)
        k = lambda t, key: t.get(key)
        print(f"| {stem} | {f(a['psnr'])} | {f(b['psnr'])} | {g(a['psnr'], b['psnr'])} / "
              f"{g(k(a, 'psnr_masked'), k(b, 'psnr_masked'))} | {f(k(a, 'psnr_covered'))} / {f(k(b, 'psnr_covered'))} | "
              f"{f(k(a, 'psnr_uncovered'))} / {f(k(b, 'psnr_uncovered'))} |")


HELD_OUT = ("public_chair",)  # kept out of every tuning decision: listed on its own


def _name(run: Path) -> str:
    """The folder's name, or for a multirun job ``<dataset>_<references>_<variant>[_s<seed>]`` from its overrides."""
    import yaml

    from arcsem.report.collect import parse_overrides

    ov = run / ".hydra" / "overrides.yaml"
    if not (run.name.isdigit() and ov.is_file()):
        return run.name
    kv = parse_overrides(yaml.safe_load(ov.read_text()))
    variant = kv.get("ablation", "full")
    switched = [name for key, (value, name) in SWITCHES.items() if str(kv.get(key)).lower() == value]
    if variant == "full" and switched:
        variant = "_".join(switched)
    seed = int(kv.get("seed", 0))
    return (f"{kv.get('dataset', 'synthetic')}_{kv.get('colorize.references', 'five')}_"
            f"{'default' if variant == 'full' else variant}" + (f"_s{seed}" if seed else ""))


SWITCHES = {"colorize.prior": ("off", "no_prior"), "colorize.surface.mode": ("off", "no_surface"),
            "colorize.shading": ("off", "no_shading"), "colorize.validate": ("off", "no_validate"),
            "colorize.guard.enabled": ("false", "no_guard")}
"""A multirun job's override that switches one addition off, and its variant name (as ``colour_runs.sh`` names
them): ``ablation=full colorize.prior=off`` is ``no_prior``."""


def _runs(dirs: list[str]) -> dict[str, Path]:
    """Run folders by name; a later DIR's run replaces an earlier one's."""
    runs: dict[str, Path] = {}
    for d in dirs:
        runs.update({_name(p.parent): p.parent for p in Path(d).glob("*/metrics.json")})
    return runs


def _paired(runs: dict[str, Path], variant: str) -> dict[str, dict[int, tuple[str, str]]]:
    """``<scene>_<refs>`` -> seed -> (the default's run, ``variant``'s run), for the seeds that have both."""
    groups: dict[str, dict[int, tuple[str, str]]] = {}
    for name in runs:
        stem, _, seed = name.partition("_default")
        if not stem or (seed and not seed.startswith("_s")):
            continue
        k = int(seed[2:]) if seed else 0
        base = f"{stem}_{variant}" + (f"_s{k}" if k else "")
        if base in runs:
            groups.setdefault(stem, {})[k] = (name, base)
    return groups


def _test(run: Path) -> dict:
    return json.loads((run / "metrics.json").read_text())["stage2"]["test"]


def _outside(a: dict, b: dict) -> float | None:
    if a.get("psnr_uncovered") is None or b.get("psnr_uncovered") is None:
        return None
    return a["psnr_uncovered"] - b["psnr_uncovered"]


def seeded(dirs: list[str]) -> None:
    """One row per ``<scene>_<refs>``: default against pseudo_only paired by seed (whole image and outside the
    coverage), for the seeds that have both runs."""
    runs = _runs(dirs)
    groups = _paired(runs, "pseudo_only")
    f = lambda x: "-" if x is None else f"{x:+.2f}"
    print("| scene, references | seeds | default (mean) | pseudo-colours (mean) | gain per seed | smallest gain | "
          "outside cov. gain per seed |")
    print("|---|---|---:|---:|---|---:|---|")
    for stem in sorted(groups):
        seeds = sorted(groups[stem])
        a = [_test(runs[groups[stem][k][0]]) for k in seeds]
        b = [_test(runs[groups[stem][k][1]]) for k in seeds]
        gains = [x["psnr"] - y["psnr"] for x, y in zip(a, b)]
        out = [_outside(x, y) for x, y in zip(a, b)]
        print(f"| {stem} | {', '.join(map(str, seeds))} | {sum(x['psnr'] for x in a) / len(a):.2f} | "
              f"{sum(y['psnr'] for y in b) / len(b):.2f} | {', '.join(f(g) for g in gains)} | {f(min(gains))} | "
              f"{', '.join(f(o) for o in out)} |")


def outside(dirs: list[str]) -> None:
    """Issue 38's second line: per reference count, each scene's mean outside-coverage gain of the default over
    pseudo-colours alone (over its seeds), their mean over the tuned scenes, the held-out scene(s) on their own, the
    mean over all, and the gain pooled over every outside pixel of every scene and seed (``10 log10`` of the
    pixel-weighted mean squared errors' ratio)."""
    runs = _runs(dirs)
    groups = _paired(runs, "pseudo_only")
    by_refs: dict[str, dict[str, list[tuple[dict, dict]]]] = {}
    for stem, seeds in groups.items():
        scene, _, refs = stem.rpartition("_")
        pairs_ = [(_test(runs[a]), _test(runs[b])) for a, b in seeds.values()]
        if all(x.get("psnr_uncovered") is not None and y.get("psnr_uncovered") is not None for x, y in pairs_):
            by_refs.setdefault(refs, {})[scene] = pairs_
    scenes = sorted({s for v in by_refs.values() for s in v}, key=lambda s: (s in HELD_OUT, s))
    tuned = [s for s in scenes if s not in HELD_OUT]
    print("| references | " + " | ".join(f"{s} (px)" + (" **held out**" if s in HELD_OUT else "") for s in scenes) +
          " | mean of the tuned | mean of all | pooled over the pixels |")
    print("|---|" + "---:|" * (len(scenes) + 3))
    for refs in ("one", "three", "five"):
        got = by_refs.get(refs, {})
        gain = {s: sum(_outside(x, y) for x, y in p) / len(p) for s, p in got.items()}
        px = {s: sum(x.get("uncovered_px") or 0 for x, _ in p) / len(p) for s, p in got.items()}
        mse = lambda t: 10 ** (-t["psnr_uncovered"] / 10) * (t.get("uncovered_px") or 0)
        pd = sum(mse(x) for p in got.values() for x, _ in p)
        pp = sum(mse(y) for p in got.values() for _, y in p)
        cells = [f"{gain[s]:+.2f} ({px[s]:.0f})" if s in gain else "-" for s in scenes]
        pooled = f"{10 * math.log10(pp / pd):+.2f}" if pd > 0 and pp > 0 else "-"
        print(f"| {refs} | " + " | ".join(cells) + f" | {_mean(gain, tuned)} | {_mean(gain, scenes)} | {pooled} |")


def _mean(gain: dict[str, float], names: list[str]) -> str:
    return f"{sum(gain[s] for s in names) / len(names):+.2f}" if names and all(s in gain for s in names) else "-"


def ablations(dirs: list[str]) -> None:
    """One row per ``<scene>_<refs>`` and variant other than the default and pseudo_only: the default's gain over it
    per seed, whole and outside the coverage, and the seed spread (max - min over the seeds) of the default's own
    outside-coverage PSNR, which issue 38's third line asks the mean gain to exceed."""
    runs = _runs(dirs)
    named = [re.search(r"_(?:one|three|five)_(.+?)(?:_s\d+)?$", name) for name in runs]
    variants = sorted({m.group(1) for m in named if m} - {"default", "pseudo_only"})
    f = lambda x: "-" if x is None else f"{x:+.2f}"
    print("| scene, references | ablation | seeds | gain per seed (whole) | gain per seed (outside cov.) | "
          "mean gain outside | default's spread outside |")
    print("|---|---|---|---|---|---:|---:|")
    for variant in variants:
        groups = _paired(runs, variant)
        for stem in sorted(groups):
            seeds = sorted(groups[stem])
            a = [_test(runs[groups[stem][k][0]]) for k in seeds]
            b = [_test(runs[groups[stem][k][1]]) for k in seeds]
            out = [_outside(x, y) for x, y in zip(a, b)]
            own = [x.get("psnr_uncovered") for x in a if x.get("psnr_uncovered") is not None]
            mean = sum(out) / len(out) if None not in out else None
            spread = max(own) - min(own) if len(own) > 1 else None
            print(f"| {stem} | {variant} | {', '.join(map(str, seeds))} | "
                  f"{', '.join(f(x['psnr'] - y['psnr']) for x, y in zip(a, b))} | {', '.join(f(o) for o in out)} | "
                  f"{f(mean)} | {'-' if spread is None else f'{spread:.2f}'} |")


def _guided(run: Path) -> str:
    """Which guided losses trained: ``TCM+CCM``, ``TCM``, ``CCM`` or ``-``."""
    trained = json.loads((run / "metrics.json").read_text())["stage2"].get("losses") or []
    return "+".join(n.upper() for n in ("tcm", "ccm") if n in trained) or "-"


def versus(old_dir: str, new_dir: str) -> None:
    """The same runs of two folders (two commits' sweeps from the same stage-1 models), paired by name: one row per
    ``<scene>_<refs>_<variant>``, the new run's gain over the old per seed, whole and outside the coverage, and the
    guided losses that trained in each."""
    old, new = _runs([old_dir]), _runs([new_dir])
    groups: dict[str, list[str]] = {}
    for name in sorted(set(old) & set(new)):
        groups.setdefault(re.sub(r"_s\d+$", "", name), []).append(name)
    f = lambda x: "-" if x is None else f"{x:+.2f}"
    print("| run | seeds | old (mean) | new (mean) | gain per seed | gain per seed outside cov. | mean gain outside | "
          "TCM/CCM old -> new |")
    print("|---|---:|---:|---:|---|---|---:|---|")
    for stem, names in groups.items():
        a, b = [_test(old[n]) for n in names], [_test(new[n]) for n in names]
        out = [_outside(y, x) for x, y in zip(a, b)]
        mean = sum(out) / len(out) if None not in out else None
        print(f"| {stem} | {len(names)} | {sum(x['psnr'] for x in a) / len(a):.2f} | "
              f"{sum(y['psnr'] for y in b) / len(b):.2f} | {', '.join(f(y['psnr'] - x['psnr']) for x, y in zip(a, b))} "
              f"| {', '.join(f(o) for o in out)} | {f(mean)} | {', '.join(_guided(old[n]) for n in names)} -> "
              f"{', '.join(_guided(new[n]) for n in names)} |")


def main(dirs: list[str]) -> None:
    if dirs and dirs[0] == "--versus" and len(dirs) == 3:
        versus(dirs[1], dirs[2])
        return
    if dirs and dirs[0] == "--seeds":
        seeded(dirs[1:])
        return
    if dirs and dirs[0] == "--outside":
        outside(dirs[1:])
        return
    if dirs and dirs[0] == "--ablations":
        ablations(dirs[1:])
        return
    if dirs and dirs[0] == "--pairs":
        for d in dirs[1:]:
            pairs(d)
        return
    print("| run | held-out PSNR | masked | inside cov. | outside cov. | px outside | reference views | target, guided losses "
          "| commit |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---|")
    for d in dirs:
        for name, run in sorted(_runs([d]).items()):
            print(row(run, name))


if __name__ == "__main__":
    main(sys.argv[1:])
