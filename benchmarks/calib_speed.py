"""Speed and memory of ``arcsem-calibrate`` on 32 images of 3072 x 2048 px (issue 18, "speed").

Input: the 32 training views of the textured synthetic scene (two arcs, orthographic) rendered at
``--render`` size (default 1152 x 768; a full-size render takes hours on 2 cores) and upsampled to 3072 x 2048
with cubic interpolation (the images therefore hold no detail finer than the render's pixels; features are
computed on a 1600-px copy anyway), saved as 8-bit PNG, with their stage angles in a CSV. The command runs
under ``/usr/bin/time -v`` (wall time and peak resident memory of the whole process) and ``uptime`` is
recorded before and after (other processes share the cores).

    .venv/bin/python benchmarks/calib_speed.py [--render 1152 768] [--out /tmp/arcsem_calib_speed]
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path


def prepare(scene: Path, folder: Path, size: tuple[int, int]) -> Path:
    """Upsampled training views in ``folder`` and their angles in ``folder.parent / tilts.csv``."""
    import cv2

    meta = json.loads((scene / "transforms.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    rows = ["file,tilt,rotation"]
    for f in meta["frames"]:
        if f["split"] != "train":
            continue
        name = Path(f["file_path"]).name
        if not (folder / name).is_file():
            img = cv2.imread(str(scene / f["file_path"]), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(folder / name), cv2.resize(img, size, interpolation=cv2.INTER_CUBIC))
        rows.append(f"{name},{f['elevation'] - 90.0:.4f},{-f['azimuth']:.4f}")
    csv = folder.parent / "tilts.csv"
    csv.write_text("\n".join(rows) + "\n")
    return csv


def main() -> None:
    from arcsem.synthetic import ensure_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--render", type=int, nargs=2, default=(1152, 768))
    ap.add_argument("--out", default="/tmp/arcsem_calib_speed")
    args, extra = ap.parse_known_args()
    scene = Path(ensure_scene(texture=0.6, camera="orthographic", width=args.render[0],
                              height=args.render[1])).parent
    folder = Path(args.out) / "input"
    csv = prepare(scene, folder, (3072, 2048))
    px = 2.5 / (0.9 * args.render[1]) * args.render[0] / 3072  # scene units per upsampled pixel
    exe = Path(sys.executable).with_name("arcsem-calibrate")
    load_before = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    cmd = ["/usr/bin/time", "-v", str(exe), str(folder), "--out", str(Path(args.out) / "dataset"), "--tilts", str(csv),
           "--pixel-size", str(px), "--overwrite", *extra]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    load_after = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    if res.returncode:
        raise SystemExit(res.stderr[-2000:])
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", res.stderr).group(1)
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", res.stderr).group(1))
    parts = [float(p) for p in wall.split(":")]
    seconds = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
    report = json.loads((Path(args.out) / "dataset" / "report" / "calibration.json").read_text())
    print(res.stdout.strip())
    print("| images | size | wall s | peak RSS GB | RMS px | stages (s) | load before / after |")
    print("|---|---|---|---|---|---|---|")
    stages = {k: round(v, 1) for k, v in report["timings_s"].items()}
    print(f"| 32 | 3072x2048 | {seconds:.0f} | {rss_kb / 1024 ** 2:.2f} | {report['rms_px']:.3f} | {stages} | "
          f"{load_before.split('load average:')[-1].strip()} / {load_after.split('load average:')[-1].strip()} |")
    (Path(args.out) / "calib_speed.json").write_text(json.dumps(
        {"seconds": seconds, "peak_rss_gb": rss_kb / 1024 ** 2, "rms_px": report["rms_px"], "stages": stages,
         "load_before": load_before, "load_after": load_after, "render": list(args.render)}, indent=1))


if __name__ == "__main__":
    main()
