"""Public multi-view scenes with true colour for the colour benchmark (issue 38), as arcsem transforms scenes.

Each dataset is read from a fetched git mirror (no work tree: ``git --git-dir=MIRROR show COMMIT:PATH``) and
written to ``OUT/<name>`` (default ``<arcsem cache root>/colour_scenes/<name>``, where ``dataset=public_<name>``
reads it; the cache root is ``$ARCSEM_CACHE`` or ``~/.cache/arcsem``):

* ``images/`` grey input views: the luminance of the colour view (Rec. 709 weights on the 8-bit values);
* ``color/`` the colour ground truth of every view (``color_path``), ``masks/`` where the dataset has alpha;
* ``references/`` the colour images of the five views of ``reference_sets`` (``one``/``three``/``five``: nested,
  chosen by farthest-point sampling of the camera directions from the training view nearest the mean direction,
  so that they are spread around the object);
* ``transforms.json`` (frames with ``split``; intrinsics at the written size; ``source`` block) and ``SOURCE.md``
  (repository, commit, paths, licence).

Usage (each ``--mirror`` defaults to ``/work/.mirror/<owner>+<name>/repo``; elsewhere make one with
``git clone --bare https://github.com/<owner>/<name> DIR`` and pass ``--mirror NAME=DIR``)::

    python benchmarks/colour_scenes.py [--out DIR] [--only chair] [--mirror chair=DIR]

Then ``arcsem dataset=transforms dataset.path=OUT/chair stage=check colorize.references=five``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # before cv2 is imported: EXR renders readable
import cv2
import numpy as np

from arcsem.data.io import LUMA  # Rec. 709, as dataset.grey=true reads a colour view
from arcsem.runconfig import cache_root

__all__ = ["DATASETS", "Source", "main", "reference_sets", "write_scene"]


@dataclass(frozen=True)
class Source:
    """One public dataset: where it lives and how to read it."""

    repo: str                 # owner/name on GitHub
    commit: str               # the snapshot read (40 hex digits)
    root: str                 # the dataset's folder inside the repository ("" = top level)
    layout: str               # "blender" (transforms_train/_test.json, RGBA PNG) | "ngp" (transforms.json, JPEG)
    licence: str
    what: str
    held_out: bool = False    # never used for a tuning decision (benchmarks/results/colour/README.md)
    width: int = 160          # written width in pixels (height keeps the aspect ratio)
    n_train: int = 40
    n_test: int = 10
    aabb: tuple = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))


DATASETS = {
    "chair": Source(
        "rounak890/nerf_data", "0a47cb5f6c1f347a58503a7b0b6138610d84c4bc", "", "blender",
        "CC-0 (the dataset's README.txt: 'chair by 1DInc (CC-0): https://www.blendswap.com/blend/8261')",
        "the NeRF-synthetic chair (Mildenhall et al. 2020): a carved armchair of a few uniformly coloured parts "
        "(green cushions, cream frame, gilt ornaments), 800 px RGBA renders on a transparent background",
        held_out=True, aabb=((-1.0, -1.0, -1.1), (1.0, 1.0, 1.1))),
    "fox": Source(
        "BoSmallEar/instant-ngp", "5cb11afb0d03cc791b8464bb93bcdbcf73390e6b", "data/nerf/fox", "ngp",
        "NVIDIA Source Code License-NC (the repository's LICENSE.txt; a fork of NVlabs/instant-ngp, whose "
        "data/nerf/fox it carries unchanged): non-commercial research use",
        "instant-ngp's fox: 50 photographs (1080 x 1920 JPEG, lens distortion) of a fox figurine in a room, "
        "no masks; real colour, not a render", width=108),
}


def git_bytes(mirror: Path, commit: str, path: str) -> bytes:
    """The bytes of ``path`` at ``commit`` in the bare mirror ``mirror``."""
    return subprocess.run(["git", f"--git-dir={mirror}", "show", f"{commit}:{path}"], check=True,
                          capture_output=True).stdout


def _decode(data: bytes, where: str) -> np.ndarray:
    """``[H, W, C]`` float RGB(A) in [0, 1] (8/16-bit or float images)."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{where}: not an image OpenCV can read")
    scale = 255.0 if img.dtype == np.uint8 else 65535.0 if img.dtype == np.uint16 else 1.0
    img = img.astype(np.float64) / scale
    order = [2, 1, 0, 3][: img.shape[2]]  # BGR(A) -> RGB(A)
    return np.clip(img[..., order], 0, 1)


def _evenly(items: list, n: int) -> list:
    """``n`` items spread evenly over ``items`` (all of them when there are fewer)."""
    if len(items) <= n:
        return list(items)
    return [items[int(i)] for i in np.linspace(0, len(items) - 1, n).round()]


def reference_sets(c2w: np.ndarray, names: list[str], centre=(0.0, 0.0, 0.0)) -> dict[str, list[str]]:
    """``{"one", "three", "five"}``: nested sets of training views spread around the object.

    ``c2w [N, 4, 4]``: the training cameras. The first is the view nearest the mean viewing direction; each
    next one the view whose direction is farthest (largest smallest angle) from those already chosen.
    """
    d = c2w[:, :3, 3] - np.asarray(centre)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    mean = d.mean(0)
    pick = [int(np.argmax(d @ mean))]
    while len(pick) < min(5, len(names)):
        pick.append(int(np.argmin((d @ d[pick].T).max(-1))))
    chosen = [names[i] for i in pick]
    return {"one": chosen[:1], "three": chosen[:3], "five": chosen}


def _blender_frames(mirror: Path, s: Source) -> list[tuple[str, str, dict, dict]]:
    """``(split, name, frame, top-level keys)`` of the views kept: evenly spaced train and test frames."""
    out = []
    for split, n in (("train", s.n_train), ("test", s.n_test)):
        meta = json.loads(git_bytes(mirror, s.commit, str(Path(s.root, f"transforms_{split}.json"))))
        top = {k: v for k, v in meta.items() if k != "frames"}
        for f in _evenly(meta["frames"], n):
            out.append((split, f"{split}_{Path(f['file_path']).name}", f, top))
    return out


def _ngp_frames(mirror: Path, s: Source) -> list[tuple[str, str, dict, dict]]:
    """As :func:`_blender_frames` for one transforms.json: every ``k``-th view (``k`` from the counts) is a test view."""
    meta = json.loads(git_bytes(mirror, s.commit, str(Path(s.root, "transforms.json"))))
    top = {k: v for k, v in meta.items() if k != "frames"}
    frames = sorted(meta["frames"], key=lambda f: f["file_path"])
    every = max(2, round(len(frames) / s.n_test))
    test = set(range(every // 2, len(frames), every))
    return [("test" if i in test else "train", Path(f["file_path"]).stem, f, top) for i, f in enumerate(frames)]


def _intrinsics(top: dict, w0: int, h0: int) -> tuple[np.ndarray, np.ndarray]:
    """``K [3, 3]`` at the source size and the OpenCV distortion ``[k1, k2, p1, p2]``."""
    fx = top["fl_x"] if "fl_x" in top else 0.5 * w0 / np.tan(0.5 * top["camera_angle_x"])
    fy = top.get("fl_y", fx)
    K = np.array([[fx, 0, top.get("cx", w0 / 2)], [0, fy, top.get("cy", h0 / 2)], [0, 0, 1.0]])
    return K, np.array([top.get(k, 0.0) for k in ("k1", "k2", "p1", "p2")], dtype=np.float64)


def _read_view(mirror: Path, s: Source, frame: dict, top: dict) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Colour ``[h, w, 3]``, alpha ``[h, w]`` (or None) at the written size, and ``K`` there."""
    path = str(Path(s.root, frame["file_path"]))
    if s.layout == "blender" and not path.endswith(".png"):
        path += ".png"
    img = _decode(git_bytes(mirror, s.commit, path), f"{s.repo}:{path}")
    h0, w0 = img.shape[:2]
    K, dist = _intrinsics(top, w0, h0)
    if np.any(dist != 0):
        img = cv2.undistort(img, K, dist)  # same K: the pinhole model of the written views
    alpha = img[..., 3] if img.shape[2] == 4 else None
    rgb = img[..., :3] * (alpha[..., None] if alpha is not None else 1)  # over black (SEM-like background)
    w = s.width
    h = round(h0 * w / w0)
    rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
    alpha = cv2.resize(alpha, (w, h), interpolation=cv2.INTER_AREA) if alpha is not None else None
    K = K.copy()
    K[:2] *= w / w0  # pixel-edge origin, as arcsem.cameras.Cameras.scaled
    return rgb, alpha, K


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def _save(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    bgr = img[..., ::-1] if img.ndim == 3 else img
    if not cv2.imwrite(str(path), _u8(bgr)):
        raise OSError(f"could not write {path}")


def _write_frame(out: Path, split: str, name: str, rgb: np.ndarray, alpha, K: np.ndarray, frame: dict) -> dict:
    """Write one view's grey, colour (and mask); its transforms.json frame."""
    _save(out / f"images/{name}.png", rgb @ LUMA)
    _save(out / f"color/{name}.png", rgb)
    f = {"file_path": f"images/{name}.png", "color_path": f"color/{name}.png", "split": split,
         "transform_matrix": frame["transform_matrix"],
         "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
         "w": rgb.shape[1], "h": rgb.shape[0]}
    if alpha is not None:
        _save(out / f"masks/{name}.png", (alpha > 0.5).astype(np.float64))
        f["mask_path"] = f"masks/{name}.png"
    return f


def write_scene(name: str, s: Source, mirror: Path, out: Path) -> Path:
    """Write dataset ``name`` from ``mirror`` into ``out``; returns its transforms.json."""
    listed = _blender_frames(mirror, s) if s.layout == "blender" else _ngp_frames(mirror, s)
    frames = [_write_frame(out, split, view, *_read_view(mirror, s, f, top), f) for split, view, f, top in listed]
    train = [f for f in frames if f["split"] == "train"]
    names = [Path(f["file_path"]).stem for f in train]
    refs = reference_sets(np.array([f["transform_matrix"] for f in train], dtype=np.float64), names)
    for f in train:
        view = Path(f["file_path"]).stem
        if view in refs["five"]:
            (out / "references").mkdir(exist_ok=True)
            (out / f"references/{view}.png").write_bytes((out / f["color_path"]).read_bytes())
            f["reference_path"] = f"references/{view}.png"
    source = {"repository": f"https://github.com/{s.repo}", "commit": s.commit, "path": s.root or ".",
              "licence": s.licence, "held_out": s.held_out}
    meta = {"camera_model": "PINHOLE", "aabb": [list(s.aabb[0]), list(s.aabb[1])], "reference_sets": refs,
            "source": source, "frames": frames}
    (out / "transforms.json").write_text(json.dumps(meta, indent=1))
    (out / "SOURCE.md").write_text(_source_md(name, s, len(train), len(frames) - len(train), refs))
    return out / "transforms.json"


def _source_md(name: str, s: Source, n_train: int, n_test: int, refs: dict) -> str:
    held = ("**Held out**: never used for a tuning decision; reported on its own.\n" if s.held_out else
            "Used for development (tuning decisions may look at it).\n")
    return (f"# {name}\n\n{s.what}.\n\n- Source: https://github.com/{s.repo} at commit `{s.commit}`, "
            f"folder `{s.root or '.'}`\n- Licence: {s.licence}\n- Written by benchmarks/colour_scenes.py: "
            f"{n_train} training and {n_test} test views, {s.width} px wide; grey input = Rec. 709 luminance of "
            f"the colour view; colour references {', '.join(refs['five'])}\n\n{held}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="parent folder of the scenes (default: <arcsem cache root>/colour_scenes, "
                    "where dataset=public_<name> looks)")
    ap.add_argument("--only", nargs="*", default=list(DATASETS), choices=list(DATASETS))
    ap.add_argument("--mirror", action="append", default=[], help="NAME=GIT_DIR (default: /work/.mirror/...)")
    args = ap.parse_args(argv)
    mirrors = dict(m.split("=", 1) for m in args.mirror)
    out = Path(args.out) if args.out else cache_root() / "colour_scenes"
    for name in args.only:
        s = DATASETS[name]
        mirror = Path(mirrors.get(name, f"/work/.mirror/{s.repo.replace('/', '+')}/repo"))
        if not (mirror / "HEAD").is_file():
            print(f"error: --mirror {name}: no git repository at {mirror}; make one with `git clone --bare "
                  f"https://github.com/{s.repo} DIR` and pass --mirror {name}=DIR", file=sys.stderr)
            return 2
        path = write_scene(name, s, mirror, out / name)
        print(f"{name}: {path}{'  (held out)' if s.held_out else ''}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
