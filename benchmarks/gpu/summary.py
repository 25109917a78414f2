"""The figures of benchmarks/gpu_check.sh, gathered (run by it; no GPU needed).

    summary.py --profile OUT/gpu_profile.json NAME               one line per profiled variant
    summary.py --demo RUN_DIR RASTERIZER SEED EXIT WALL_S DMON OUT.json   one demo job's figures, appended to OUT.json
    summary.py --check OUT                                         OUT/gpu_check.json from all of the above
    summary.py --stamp < LOG                                       each line of LOG after its seconds since the start
"""
from __future__ import annotations

import json
import os
import re
import sys
import time
from pathlib import Path


def _load(path: Path, default):
    return json.loads(path.read_text()) if path.is_file() else default


def profile_line(path: str, name: str) -> None:
    rows = [x for x in _load(Path(path), []) if x["name"] == name]
    if not rows:
        print(f"{name}: no profile")
        return
    r = rows[-1]
    print(f"{name}: {r['stage1_steps_per_s']} steps/s, SM {r['sm_util_pct']} %, {r['syncs_per_step']} syncs/step, "
          f"{r['kernel_launches_per_step']} launches/step, {r['aten_calls_per_step']} aten calls/step, GPU kernels "
          f"{r['gpu_kernel_ms_per_step']} ms/step, {r['primitives']} primitives")
    print("  syncs:", list(r["sync_sites"].items())[:10])
    print("  kernels:", r["top_kernels_ms_per_step"][:8])
    print("  cpu ops:", r["top_cpu_ops_ms_per_step"][:8])


def dmon_sm(path: Path) -> list[float]:
    """The ``sm`` column of ``nvidia-smi dmon -s u -o T`` (time, gpu, sm, mem, ...)."""
    out = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        parts = line.split()
        if len(parts) > 3 and re.fullmatch(r"\d\d:\d\d:\d\d", parts[0]) and parts[2].isdigit():
            out.append(float(parts[2]))
    return out


def demo_record(run_dir: str, name: str, seed: str, rc: str, wall: str, dmon: str, out: str) -> None:
    m = _load(Path(run_dir) / "metrics.json", {})
    s1, s2 = m.get("stage1") or {}, m.get("stage2") or {}
    sm = dmon_sm(Path(dmon))
    rec = {"rasterizer": name, "seed": int(seed), "exit": int(rc), "wall_s": float(wall), "status": m.get("status"),
           "stage1_steps_per_s": s1.get("steps_per_s"), "stage1_time_s": s1.get("time_s"),
           "stage1_test_psnr": (s1.get("test") or {}).get("psnr"), "stage1_test_ssim": (s1.get("test") or {}).get("ssim"),
           "mesh_gt": (s1.get("mesh") or {}).get("gt"),
           "stage2_complete": "color" in (m.get("completed_stages") or []),
           "stage2_steps_per_s": s2.get("steps_per_s"), "stage2_test_psnr": (s2.get("test") or {}).get("psnr"),
           "timings": m.get("timings"), "sm_util_pct_whole_job": round(sum(sm) / len(sm), 1) if sm else None}
    p = Path(out)
    p.write_text(json.dumps(_load(p, []) + [rec], indent=1))
    print(json.dumps(rec))


def check(out_dir: str) -> None:
    out = Path(out_dir)
    log = (out / "cuda_tests.log").read_text() if (out / "cuda_tests.log").is_file() else ""
    count = lambda word: sum(int(n) for n in re.findall(rf"(\d+) {word}", log.splitlines()[-1] if log else ""))
    prof = {r["name"]: r for r in _load(out / "gpu_profile.json", [])}
    demos = {r["rasterizer"]: r for r in _load(out / "demo_metrics.json", [])}
    default = demos.get("auto", {})
    device = out / "device.txt"
    res = {
        "device": device.read_text().strip() if device.is_file() else next((r["device"] for r in prof.values()), None),
        "cuda_tests_passed": count("passed") if log else None,
        "cuda_tests_failed": (count("failed") + count("error")) if log else None,
        "stage1_steps_per_s": default.get("stage1_steps_per_s"),
        # stage 1's profile (steps 50-250) when one ran, else the whole demo job's dmon mean
        "sm_util_pct": (prof.get("gs2d") or {}).get("sm_util_pct") or default.get("sm_util_pct_whole_job"),
        "sm_util_from": "stage-1 profile" if "gs2d" in prof else ("whole demo job" if default else None),
        "stage2_complete": default.get("stage2_complete"),
        "demo_wall_s": default.get("wall_s"),
        "demo": demos,
        "quality": quality(list(demos.values()) + _load(out / "quality_metrics.json", [])),
        "profile": {k: {f: v[f] for f in ("stage1_steps_per_s", "sm_util_pct", "syncs_per_step",
                                          "kernel_launches_per_step", "aten_calls_per_step", "gpu_kernel_ms_per_step",
                                          "primitives")} for k, v in prof.items()},
    }
    text = json.dumps(res, indent=1)
    (out / "gpu_check.json").write_text(text)
    print(text)


def quality(records: list[dict]) -> dict:
    """Held-out grey (stage 1) and colour (stage 2) PSNR per rasteriser and seed, and their means over seeds."""
    res = {}
    for r in sorted(records, key=lambda r: (r["rasterizer"], r.get("seed", 0))):
        row = res.setdefault(r["rasterizer"], {"seeds": {}})
        row["seeds"][str(r.get("seed", 0))] = {"grey": r.get("stage1_test_psnr"), "colour": r.get("stage2_test_psnr")}
    for row in res.values():
        for key in ("grey", "colour"):
            vals = [v[key] for v in row["seeds"].values() if v[key] is not None]
            row[f"{key}_mean"] = sum(vals) / len(vals) if vals else None
    return res


def stamp() -> None:
    """Each line of stdin after the seconds at which its first byte came. A progress bar's carriage returns end a
    line too (a bar writes ``\\r`` before its text, so each refresh is a line of its own, stamped when written)."""
    t0, rest, since = time.monotonic(), b"", 0.0
    while chunk := os.read(sys.stdin.fileno(), 65536):
        now = time.monotonic() - t0
        since = since if rest else now  # a line that starts in this chunk starts now
        *lines, tail = re.split(rb"[\r\n]", rest + chunk)
        for i, line in enumerate(lines):
            if line.strip():
                print(f"{since if i == 0 else now:7.1f} {line.decode(errors='replace').rstrip()}", flush=True)
        since = since if not lines else now
        rest = tail
    if rest.strip():
        print(f"{since:7.1f} {rest.decode(errors='replace').rstrip()}", flush=True)


if __name__ == "__main__":
    mode, args = sys.argv[1], sys.argv[2:]
    {"--profile": profile_line, "--demo": demo_record, "--check": check, "--stamp": stamp}[mode](*args)
