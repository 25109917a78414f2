#!/usr/bin/env bash
# Stage 2's wall time at the demo's size, two checkouts side by side (issue 38's "at most 1.3x" line): both colour
# the same stage-1 run (`experiment=demo stage=color colorize.stage1=STAGE1_RUN`), one thread each, started
# together, REPEATS rounds; prints each round and the medians of stage 2's training time and its whole time.
#   benchmarks/stage2_ab.sh BASE_ARCSEM HEAD_ARCSEM STAGE1_RUN OUT [REPEATS]
# BASE_ARCSEM / HEAD_ARCSEM: the `arcsem` executables of the two checkouts (e.g. a worktree at the older commit
# with its own virtual environment; benchmarks/results/README.md, "Benchmark scripts").
set -euo pipefail
BASE=${1:?base arcsem}; HEAD=${2:?head arcsem}; S1=${3:?stage-1 run}; OUT=${4:?output folder}; REPEATS=${5:-3}
mkdir -p "$OUT"
for r in $(seq 1 "$REPEATS"); do
  for side in base head; do
    bin=$BASE; [ "$side" = head ] && bin=$HEAD
    "$bin" experiment=demo stage=color colorize.stage1="$S1" threads=1 colorize.progress=false \
      hydra.run.dir="$OUT/${side}_$r" > "$OUT/${side}_$r.log" 2>&1 &
  done
  wait
done
python3 - "$OUT" "$REPEATS" <<'PY'
import json, statistics, sys
from pathlib import Path
out, n = Path(sys.argv[1]), int(sys.argv[2])
rows = {}
for side in ("base", "head"):
    for r in range(1, n + 1):
        m = json.loads((out / f"{side}_{r}" / "metrics.json").read_text())
        s2 = m.get("stage2") or {}
        rows.setdefault(side, []).append((s2.get("time_s"), (m.get("timings") or {}).get("color_s"),
                                          (s2.get("test") or {}).get("psnr"), m.get("git_revision", "")[:7]))
for side, vals in rows.items():
    for r, v in enumerate(vals, 1):
        print(f"{side} round {r}: training {v[0]:.1f} s, stage 2 in all {v[1]:.1f} s, held-out colour {v[2]:.2f} dB, {v[3]}")
med = {s: (statistics.median(v[0] for v in vals), statistics.median(v[1] for v in vals)) for s, vals in rows.items()}
print(f"median: base {med['base'][1]:.1f} s, head {med['head'][1]:.1f} s in all: head/base {med['head'][1] / med['base'][1]:.2f}x "
      f"(training {med['head'][0] / med['base'][0]:.2f}x)")
PY
