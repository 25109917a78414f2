"""Write a synthetic scene to disk in the ``transforms.json`` layout (plus PLY, COLMAP, contact sheet).

Layout of ``out_dir`` (see ``README.txt`` written next to it):
``transforms.json``, ``images/`` (8-bit grey; noisy + drifting exposure for train views, clean for
test views), ``clean/`` (noise-free, no drift), ``color/`` (RGB ground truth), ``masks/`` (255 =
specimen), ``depth/`` (float32 camera z, 0 = not specimen), ``normals/`` (float32 world normals),
``references/`` (the five artist views = their ground-truth colour), ``points3d.ply``,
``colmap/sparse/0/`` (pinhole only) and ``contact_sheet.png``.
"""
from __future__ import annotations

import contextlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from ..ply import write_points
from ..registry import checked
from .cameras import ViewSpec, arc_cameras, arc_views
from .render import RenderConfig, ViewImages, render_views
from .sdf import make_grain
from .shading import drift_and_noise, exposure_drift
from .sheet import contact_sheet

__all__ = ["GENERATOR_VERSION", "SPECIMENS", "SceneParams", "generate_scene", "make_specimen", "params_record",
           "reference_sets", "true_exposures"]

GENERATOR_VERSION = 2  # bump when the output of the same parameters changes (invalidates caches)
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes
SPECIMENS = ("grain", "diatom", "parts")  # the built-in specimens (``dataset.specimen``)


@dataclass(frozen=True)
class SceneParams:
    """Everything the scene depends on (hashed for the cache folder)."""

    seed: int = 0
    width: int = checked(288, ge=11)  # 11: the SSIM window (arcsem.preflight.MIN_IMAGE_SIZE)
    height: int = checked(192, ge=11)
    camera: str = checked("pinhole", choices=("pinhole", "orthographic"))  # pinhole: near-orthographic, the paper's
    n_horizontal: int = checked(20, ge=3)
    n_vertical: int = checked(12, ge=2)
    substrate: bool = True
    supersample: int = checked(2, ge=1)  # s x s samples on silhouette pixels
    noise: float = checked(0.03, ge=0.0)  # per-pixel Gaussian scan noise (train images)
    row_jitter: float = checked(0.015, ge=0.0)  # per-scan-line brightness noise (train images)
    drift: float = checked(0.05, ge=0.0)  # per-image log-contrast / brightness drift, x(1 + 2 el/85) on the vertical arc
    n_spines: int = checked(30, ge=0)
    test_every: int = checked(4, ge=1)  # one test view in every 4th gap of each arc
    specimen: str = checked("grain", choices=SPECIMENS)  # the pollen grain | arcsem.synthetic.diatom | .parts
    texture: float = checked(0.0, ge=0.0, lt=1.0)  # surface texture amplitude on specimen and substrate (0.3: SEM-like)
    texture_scale: float = checked(0.05, gt=0.0)  # its coarsest lattice spacing, in specimen sizes (3 octaves finer)

    @classmethod
    def from_transforms(cls, meta: dict) -> SceneParams:
        """The parameters a generated scene was made with, from its ``transforms.json`` (``meta["synthetic"]``)."""
        if "synthetic" not in meta:
            raise ValueError("transforms.json has no 'synthetic' block: not a scene of the built-in generator")
        return cls(**{k: v for k, v in meta["synthetic"].items() if k in cls.__dataclass_fields__})


def params_record(p: SceneParams) -> dict:
    """The parameters as recorded (cache key, ``transforms.json``, README): ``specimen`` only when it is not
    the grain and the texture only when there is one, so the built-in scene's files and cache folder stay what
    they were before specimens and textures existed."""
    d = asdict(p)
    if d["specimen"] == "grain":
        del d["specimen"]
    if d["texture"] == 0:  # the untextured scenes keep their files and cache folders
        del d["texture"], d["texture_scale"]
    return d


def make_specimen(p: SceneParams):
    """The specimen of ``p``: :func:`~arcsem.synthetic.sdf.make_grain`, :func:`~arcsem.synthetic.diatom.make_diatom`
    or :func:`~arcsem.synthetic.parts.make_parts`."""
    if p.specimen == "grain":
        return make_grain(p.seed, p.n_spines)
    if p.specimen == "diatom":
        from .diatom import make_diatom

        return make_diatom(p.seed)
    if p.specimen == "parts":
        from .parts import make_parts

        return make_parts(p.seed)
    from ..errors import ConfigError

    raise ConfigError(f"synthetic scene: unknown specimen '{p.specimen}'; available: {', '.join(SPECIMENS)}")


def reference_sets(views: list[ViewSpec]) -> dict[str, list[str]]:
    """The paper's reference sets by name: five = leftmost, centre, rightmost, angled, top."""
    h = [v.name for v in views if v.split == "train" and v.arc == "h"]
    v = [v.name for v in views if v.split == "train" and v.arc == "v"]
    left, centre, right, angled, top = h[0], h[len(h) // 2], h[-1], v[len(v) // 2], v[-1]
    return {"five": [left, centre, right, angled, top], "four": [left, centre, right, angled],
            "three": [left, centre, right], "two": [centre, right], "one": [centre]}


@contextlib.contextmanager
def _one_thread():
    """Rendering runs many small tensor ops: one intra-op thread is faster on a busy 2-core box."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def generate_scene(out_dir, *, progress: bool | None = None, **params) -> Path:
    """Render the synthetic scene of ``SceneParams(**params)`` into ``out_dir``; returns transforms.json."""
    p = SceneParams(**params)
    if p.width < 8 or p.height < 8:
        from ..errors import ConfigError

        raise ConfigError(f"synthetic scene: width/height must be >= 8, got {p.width}x{p.height}")
    grain = make_specimen(p)
    out = Path(out_dir)
    for sub in ("images", "clean", "color", "masks", "depth", "normals", "references"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    views = arc_views(p.n_horizontal, p.n_vertical, p.test_every)
    cams, distance = arc_cameras(views, p.width, p.height, p.camera)
    cfg = RenderConfig(supersample=p.supersample, substrate=p.substrate, texture=p.texture,
                       texture_scale=p.texture_scale, texture_seed=p.seed)
    refs = reference_sets(views)
    n_train = sum(v.split == "train" for v in views)
    # views are rendered in groups of at most cfg.chunk pixels and written at once: memory stays
    # bounded at any resolution (3072x2048: one view per group, rays in chunks)
    per_group = max(1, cfg.chunk // (p.width * p.height))
    groups = [list(range(i, min(i + per_group, len(views)))) for i in range(0, len(views), per_group)]
    show = progress if progress is not None else p.width * p.height >= 1_000_000
    frames, clouds = [], []
    with _one_thread():
        for grp in _progress(groups, show):
            renders = render_views(grain, cams[torch.tensor(grp)], cfg)
            for i, r in zip(grp, renders):
                v = views[i]
                frames.append(_write_view(out, p, i, v, r, v.name in refs["five"]))
                if v.split == "train":
                    clouds.append(_sample_points(r, np.random.default_rng([p.seed, i, 7]), 20_000 // n_train))
    pts = np.concatenate([c[0] for c in clouds])
    cols = np.repeat(np.concatenate([c[1] for c in clouds])[:, None], 3, 1)
    write_points(out / "points3d.ply", pts, cols / 255.0)  # uint8 grey -> [0, 1] -> written back as uchar
    meta = _transforms(p, cams, frames, refs, grain, distance)
    (out / "transforms.json").write_text(json.dumps(meta, indent=1))
    if p.camera == "pinhole":
        from .colmap import write_colmap

        write_colmap(out / "colmap" / "sparse" / "0", cams, [v.name for v in views], pts, cols)
    greys = [(v.name, np.asarray(Image.open(out / f"images/{v.name}.png"))) for v in views if v.split == "train"]
    cref = [(n, np.asarray(Image.open(out / f"references/{n}.png"))) for n in refs["five"]]
    contact_sheet(greys, cref, out / "contact_sheet.png")
    (out / "README.txt").write_text(_readme(p))
    return out / "transforms.json"


def _transforms(p: SceneParams, cams, frames: list[dict], refs: dict, grain, distance: float) -> dict:
    """The ``transforms.json`` content (frames get their OpenGL camera-to-world matrices)."""
    K = cams.K[0].numpy()
    for f, m in zip(frames, cams.cam_to_world.numpy()):
        f["transform_matrix"] = (m @ FLIP).tolist()
    return {
        "camera_model": "PINHOLE" if p.camera == "pinhole" else "ORTHOGRAPHIC",
        "fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
        "w": p.width, "h": p.height, "aabb": grain.aabb.tolist(), "ply_file_path": "points3d.ply",
        "reference_sets": refs, "frames": frames,
        "synthetic": {**params_record(p), "generator_version": GENERATOR_VERSION, "camera_distance": distance,
                      "grain_size": grain.size, "world_up": [0, 0, 1], "substrate_z": grain.substrate_z},
    }


def drift_strength(p: SceneParams, v: ViewSpec) -> float:
    """The exposure-drift sigma of a training view: ``p.drift``, up to 3x towards the top of the vertical arc."""
    return p.drift * (1 + 2 * v.elevation / 85.0 if v.arc == "v" else 1.0)


def view_rng(p: SceneParams, index: int) -> np.random.Generator:
    """The generator of view ``index``'s drift and noise (its first two draws: :func:`exposure_drift`)."""
    return np.random.default_rng([p.seed, index])


def true_exposures(p: SceneParams) -> dict[str, tuple[float, float]]:
    """``{training view name: (contrast, brightness)}``: the drift the scene's training images were given.

    The observed image is ``clip(contrast * clean + brightness + noise)``; ACT should learn this up to one
    affine map shared by all views (experiments/act/act_drift.py compares them).
    """
    views = arc_views(p.n_horizontal, p.n_vertical, p.test_every)
    return {v.name: exposure_drift(view_rng(p, i), drift_strength(p, v))
            for i, v in enumerate(views) if v.split == "train"}


def _u8(x) -> np.ndarray:
    return np.clip(np.round(np.asarray(x, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def _write_view(out: Path, p: SceneParams, i: int, v: ViewSpec, r: ViewImages, is_ref: bool) -> dict:
    clean = r.grey.numpy()
    if v.split == "train":
        observed = drift_and_noise(clean, view_rng(p, i), drift_strength(p, v), p.noise, p.row_jitter)
    else:
        observed = clean
    n = v.name
    Image.fromarray(_u8(observed), "L").save(out / f"images/{n}.png")
    Image.fromarray(_u8(clean), "L").save(out / f"clean/{n}.png")
    Image.fromarray(_u8(r.color.numpy()), "RGB").save(out / f"color/{n}.png")
    Image.fromarray(r.mask.numpy().astype(np.uint8) * 255, "L").save(out / f"masks/{n}.png")
    np.save(out / f"depth/{n}.npy", r.depth.numpy().astype(np.float32))
    np.save(out / f"normals/{n}.npy", r.normal.numpy().astype(np.float32))
    frame = {"file_path": f"images/{n}.png", "split": v.split, "mask_path": f"masks/{n}.png",
             "depth_path": f"depth/{n}.npy", "normal_path": f"normals/{n}.npy", "color_path": f"color/{n}.png",
             "clean_path": f"clean/{n}.png", "arc": v.arc, "azimuth": v.azimuth, "elevation": v.elevation}
    if is_ref:
        Image.fromarray(_u8(r.color.numpy()), "RGB").save(out / f"references/{n}.png")
        frame["reference_path"] = f"references/{n}.png"
    return frame


def _sample_points(r: ViewImages, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n`` specimen surface points ``[P, 3]`` float32 of a view with their grey uint8 ``[P]``."""
    pts, grey = r.points.numpy(), r.point_grey.numpy()
    pick = np.sort(rng.choice(len(pts), size=min(n, len(pts)), replace=False))
    return pts[pick].astype(np.float32), _u8(grey[pick])


def _progress(items: list, show: bool):
    if not show:
        return items
    from tqdm import tqdm

    return tqdm(items, desc="synthetic scene", unit="group")


_OTHER_SPECIMEN = {  # the README's first lines for a specimen other than the grain
    "diatom": "Specimen: a centric diatom frustule (arcsem.synthetic.diatom); 'grain' below means this specimen,\n"
              "whose substrate plane lies at z = -0.6.\n",
    "parts": "Specimen: a body with pores, spines and debris, coloured by part (arcsem.synthetic.parts); 'grain'\n"
             "below means this specimen, whose substrate plane (sand-coloured) lies at z = -0.85.\n",
}


def _readme(p: SceneParams) -> str:
    colmap = ("colmap/sparse/0: COLMAP model (PINHOLE) of the same cameras and the point cloud.\n"
              if p.camera == "pinhole" else
              "No COLMAP model: COLMAP has no orthographic camera model; use transforms.json.\n")
    other = _OTHER_SPECIMEN.get(p.specimen, "")
    return other + (
        "Synthetic SEM scene written by arcsem.synthetic (arcsem-make-scene).\n"
        f"Parameters: {json.dumps(params_record(p))}\n\n"
        "World: z up (the grain's polar axis), grain centred at the origin, grain size 2 units;\n"
        "substrate plane z = -1 (shaded, but not specimen: masks, depth and normals are 0 there).\n"
        f"Cameras: {p.n_horizontal} views on a horizontal arc (h_00 left .. right, azimuth -60..60 deg,\n"
        f"elevation 10 deg), {p.n_vertical} on a vertical arc (v_00 front .. top, elevation 0..85 deg);\n"
        "test views test_h_k / test_v_k half-way between views k and k+1 (every 4th gap).\n"
        "Pinhole: the paper's focal (50,000 px at 3072 px width, scaled), cameras ~58 units away.\n"
        "transforms.json: camera-to-world in OpenGL axes; for ORTHOGRAPHIC fl_x = pixels per unit.\n"
        "images/: what a microscope would give (train: exposure drift + scan noise; test: clean).\n"
        "clean/: noise-free, drift-free grey; color/: ground-truth colour; references/: the five\n"
        "artist views (leftmost, centre, rightmost, angled, top) = their ground-truth colour.\n"
        "depth/*.npy: float32 camera z-depth (0 = not specimen); normals/*.npy: float32 world normals.\n"
        + colmap
    )
