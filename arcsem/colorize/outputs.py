"""Stage-2 outputs: colour metrics against ground truth, coloured views, previews, video, export,
coloured mesh and viewer folder."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from ..metrics import metric_convention

__all__ = ["colour_split", "evaluate_and_write", "evaluate_colour", "write_colored_products", "write_heldout",
           "write_outputs"]


def colour_split(split, idx: list[int]):
    """The views ``idx`` of ``split`` with ground-truth COLOUR as their target images."""
    sub = split.subset(idx)
    return dataclasses.replace(sub, images=sub.colors, clean=None, depths=None)


def evaluate_colour(backbone, scene, refs, run_dir: Path, cc, progress: bool = False) -> dict:
    """PSNR/SSIM/LPIPS (whole image and ``_masked``) vs ground-truth colour over non-reference training
    views (``train_nonref``), reference views (``train_ref``) and held-out views (``test``)."""
    from ..train.evaluate import evaluate_split, write_views_csv

    out: dict = {}
    rows: list = []
    ref_set = set(refs.indices.tolist())
    train = scene.train
    parts = []
    if train.colors is not None:
        parts += [("train_nonref", train, [i for i in range(len(train)) if i not in ref_set]),
                  ("train_ref", train, sorted(ref_set))]
    if scene.test.colors is not None and len(scene.test):
        parts.append(("test", scene.test, list(range(len(scene.test)))))
    if not parts:
        return {"train_nonref": {}, "test": {}, "note": "the dataset has no ground-truth colour: no colour metrics"}
    weights = set()
    for name, split, idx in parts:
        if not idx:
            out[name] = {}
            continue
        limit = cc.eval.max_train_views if name.startswith("train") else None
        lpips = cc.eval.lpips and (cc.eval.lpips_splits == "all" or name == "test")
        r, summary, _ = evaluate_split(backbone, colour_split(split, idx), split_name=name, length_scale=scene.scale[0],
                                       with_lpips=lpips, max_views=limit, metrics=cc.eval.metrics,
                                       progress=progress)
        status = summary.pop("lpips_weights", "skipped")
        if lpips:  # a part LPIPS skipped says nothing of the weights
            weights.add(status)
        for k in [k for k in summary if k.startswith("depth")]:
            summary.pop(k)
        out[name], rows = summary, rows + r
    out["lpips_weights"] = "; ".join(sorted(weights)) or "skipped"
    out["metrics_convention"] = metric_convention(cc.eval.metrics)
    out["lpips_splits"] = cc.eval.lpips_splits
    write_views_csv(Path(run_dir) / "colorize" / "views.csv", rows)
    return out


def evaluate_and_write(backbone, scene, refs, run_dir: Path, cc, coverage: tuple, pseudo: tuple, timings: dict) -> dict:
    """After training: the colour metrics (:func:`evaluate_colour`, with the coverage split of
    :func:`~arcsem.colorize.coverage.coverage_metrics`; ``coverage``: the training views' masks and pseudo-colour
    reach ``[N, H, W]``) then the outputs (:func:`write_outputs`; ``pseudo``: the target and where it holds), each
    view rendered once for all of them (:class:`~arcsem.colorize.memo.RenderMemo`); phases timed into ``timings``."""
    from ..timing import phase
    from .coverage import coverage_metrics
    from .memo import RenderMemo

    views = RenderMemo(backbone)
    with phase(timings, "evaluate"):  # metrics (whole, inside and outside the coverage)
        result = evaluate_colour(views, scene, refs, run_dir, cc, progress=cc.progress)
        for part, extra in coverage_metrics(views, scene, refs, *coverage, cc).items():
            result.setdefault(part, {}).update(extra)
    with phase(timings, "outputs"):  # renders, videos
        result.update(write_outputs(backbone, scene, run_dir, cc, *pseudo, progress=cc.progress, views=views))
    result["post_renders"] = {"renders": views.renders, "reused": views.hits}
    return result


def _png(folder: Path, name: str, img: torch.Tensor) -> None:
    from ..guard import out_path
    from ..visual import to_uint8, write_png

    write_png(out_path(folder, name, ".png"), to_uint8(img))


def write_outputs(backbone, scene, run_dir: Path, cc, pseudo: torch.Tensor, valid: torch.Tensor,
                  progress: bool = False, views=None) -> dict:
    """``colored/<view name>.png`` (every training view), ``colorize/pseudo/<name>.png``, the held-out views
    (:func:`write_heldout`), ``colored_turntable.*`` and ``colored_model.<ext>``; returns their paths. ``views``:
    what renders the training and held-out views (a :class:`~arcsem.colorize.memo.RenderMemo`; default the model)."""
    from ..train.stage1 import turntable

    run_dir = Path(run_dir)
    split = scene.train
    views = views if views is not None else backbone
    with torch.no_grad():
        for i in range(len(split)):
            _png(run_dir / "colored", split.names[i], views.render(split.cameras[i:i + 1])["rgb"][0].clamp(0, 1).cpu())
            _png(run_dir / "colorize" / "pseudo", split.names[i], pseudo[i] * valid[i][..., None])
    out = {"colored_dir": str(run_dir / "colored"), **write_heldout(views, scene.test, run_dir)}
    if cc.eval.video:
        out["video"] = str(turntable(backbone, scene, run_dir / "colored_turntable", cc.eval.video_frames, cc.eval.fps,
                                     progress=progress))
    suffix = backbone.export_suffix
    try:
        backbone.export(str(run_dir / f"colored_model{suffix}"))
        out["export"] = str(run_dir / f"colored_model{suffix}")
    except NotImplementedError:
        out["export"] = None
    return out


def write_heldout(backbone, test, run_dir: Path) -> dict:
    """``colorize/renders/test/<view>.png``: the coloured render of every held-out view, beside the grey ones of
    stage 1 (``renders/test/``), with its ground-truth colour as ``<view>_gt.png`` where the dataset has it."""
    if not len(test):
        return {}
    folder = Path(run_dir) / "colorize" / "renders" / "test"
    with torch.no_grad():
        for i in range(len(test)):
            _png(folder, test.names[i], backbone.render(test.cameras[i:i + 1])["rgb"][0].clamp(0, 1).cpu())
            if test.colors is not None:
                _png(folder, f"{test.names[i]}_gt", test.colors[i].float())
    return {"heldout_dir": str(folder)}


def write_colored_products(cfg, backbone, scene, run_dir: Path, steps: int, progress: bool) -> dict:
    """The coloured mesh (``colored_mesh.*``) and viewer folder (``colored_viewer/``). The mesh is not scored against
    the true surface again: stage 2 freezes the geometry, so its Chamfer distance is stage 1's (``stage1.mesh.gt``)."""
    from ..train.products import write_products

    return write_products(cfg, backbone, scene, run_dir, prefix="colored_", iteration=steps, progress=progress,
                          evaluate=False)
