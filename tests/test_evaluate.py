"""Evaluation: metrics against hand-computed values, depth error, renders/CSV/video, run_stage1 end to end."""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import pytest
import torch
from omegaconf import OmegaConf
from trainer_util import TinyImage, tiny_scene  # noqa: F401  (registers _tiny_image)

from arcsem.errors import TrainingError
from arcsem.plugins import BACKBONES, Backbone
from arcsem.rotations import quat_to_rotmat, rotmat_to_quat
from arcsem.runs import load_stage1
from arcsem.train import run_stage1
from arcsem.train.evaluate import depth_error, evaluate_split
from arcsem.video import arc_path

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one torch thread


@BACKBONES.register("_oracle")
class Oracle(Backbone):
    """Renders the tiny scene's clean image + ``offset`` and the GT depth + ``depth_offset``."""

    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        offset: float = 0.1
        depth_offset: float = 0.05

    def __init__(self, cfg, scene=None, act=None):
        super().__init__(cfg)
        self.register_buffer("base", scene.train.clean[0].clone())
        self.dummy = torch.nn.Parameter(torch.zeros(1))

    def render(self, cams, **kw):
        C = len(cams)
        rgb = (self.base + self.cfg.offset + 0 * self.dummy)[None].expand(C, -1, -1, -1)
        depth = torch.full_like(rgb[..., :1], 2.0 + self.cfg.depth_offset)
        return {"rgb": rgb, "alpha": torch.ones_like(depth), "depth": depth}

    def param_groups(self, stage):
        return {"dummy": [self.dummy]}


def test_clean_targets_are_scored_with_the_mean_act_observed_ones_with_the_views_own():
    """A noise-free image has no exposure drift: against it a training view is rendered with the mean
    ACT (image id -1); against the observed image, with its own (the paper's protocol)."""
    import dataclasses

    scene = tiny_scene()
    bb = BACKBONES.build({"name": "_oracle"}, scene=scene)
    seen = []
    render = bb.render
    bb.render = lambda cams, **kw: (seen.append(cams.image_ids.tolist()), render(cams, **kw))[1]
    split = scene.train
    assert split.clean is not None and split.cameras.image_ids.tolist() == list(range(len(split)))
    evaluate_split(bb, split, split_name="train", with_lpips=False)
    assert seen == [[-1]] * len(split)
    seen.clear()
    evaluate_split(bb, dataclasses.replace(split, clean=None), split_name="train", with_lpips=False)
    assert seen == [[i] for i in range(len(split))]
    seen.clear()  # the paper's protocol asked for explicitly: own ACT, observed images, even with clean ones
    rows, _, _ = evaluate_split(bb, split, split_name="train_paper", with_lpips=False, protocol="paper",
                                metrics="skimage")
    assert seen == [[i] for i in range(len(split))]
    from arcsem.metrics import psnr

    want = [psnr(render(split.cameras[i:i + 1])["rgb"][0].clamp(0, 1), split.images[i]) for i in range(len(split))]
    assert [r["psnr"] for r in rows] == pytest.approx(want), "scored against the observed images"
    with pytest.raises(ValueError, match="noise-free"):
        evaluate_split(bb, dataclasses.replace(split, clean=None), protocol="clean")


def test_depth_error_inside_gt_mask():
    gt = torch.tensor([[0.0, 2.0], [2.0, 3.0]])
    pred = torch.tensor([[9.0, 2.5], [1.0, 3.0]])
    mask = torch.tensor([[True, True], [True, False]])
    # valid: gt > 0 and mask -> (0,1) err 0.5, (1,0) err 1.0
    assert sorted(depth_error(pred, gt, mask).tolist()) == [0.5, 1.0]
    assert sorted(depth_error(pred, gt, None).tolist()) == [0.0, 0.5, 1.0]


def test_metrics_of_a_known_offset(tmp_path):
    scene = tiny_scene()
    bb = BACKBONES.build({"name": "_oracle"}, scene=scene)
    rows, summary, _ = evaluate_split(bb, scene.test, split_name="test", length_scale=scene.size, out_dir=tmp_path,
                                      with_lpips=False, metrics="skimage")
    # rgb = clean + 0.1 everywhere -> MSE 0.01 -> 20 dB, inside the mask too (float renders: no 8-bit rounding)
    assert summary["psnr"] == pytest.approx(20.0, abs=1e-3)
    assert summary["psnr_masked"] == pytest.approx(20.0, abs=1e-3)
    assert math.isnan(summary["lpips"])
    # depth 2.05 vs GT 2 inside the mask; scene.size = |(2,2,2)| = 3.4641
    assert summary["depth_mae"] == pytest.approx(0.05, abs=1e-6)
    assert summary["depth_mae_pct"] == pytest.approx(100 * 0.05 / math.sqrt(12), rel=1e-5)
    assert [r["name"] for r in rows] == scene.test.names
    for n in scene.test.names:
        assert (tmp_path / "renders" / "test" / f"{n}.png").is_file()
        for suffix in ("_depth", "_gt", "_depth_gt"):
            assert (tmp_path / "renders" / "test" / f"{n}{suffix}.png").is_file()
    import imageio.v2 as imageio

    gt = imageio.imread(tmp_path / "renders" / "test" / f"{scene.test.names[0]}_gt.png")
    assert abs(gt.astype(float) / 255 - scene.test.clean[0].numpy()).max() <= 0.5 / 255 + 1e-6


def test_quaternions_round_trip():
    g = torch.Generator().manual_seed(0)
    q = torch.randn(50, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    q = torch.where(q[:, :1] < 0, -q, q)
    torch.testing.assert_close(rotmat_to_quat(quat_to_rotmat(q)), q)


def test_rotmat_to_quat_takes_any_batch_shape():
    """One matrix ``[3, 3]`` -> ``[4]``; ``[2, 5, 3, 3]`` -> ``[2, 5, 4]``, each equal to the flat batch's (the gsplat
    CUDA test passed one matrix and met 'too many indices')."""
    g = torch.Generator().manual_seed(1)
    q = torch.randn(10, 4, generator=g, dtype=torch.float64)
    q = torch.where(q[:, :1] < 0, -q, q) / q.norm(dim=-1, keepdim=True)
    R = quat_to_rotmat(q)
    torch.testing.assert_close(rotmat_to_quat(R[3]), q[3])
    torch.testing.assert_close(rotmat_to_quat(R.reshape(2, 5, 3, 3)), q.reshape(2, 5, 4))
    with pytest.raises(ValueError, match=r"\[\.\.\., 3, 3\]"):
        rotmat_to_quat(torch.eye(4))


def test_arc_path_passes_through_training_cameras_and_stays_on_the_arc():
    scene = tiny_scene(n=4)
    cams = scene.train.cameras
    path = arc_path(cams, 7, torch.zeros(3))  # t = 0, .5, 1, ..., 3
    torch.testing.assert_close(path.world_to_cam[::2], cams.world_to_cam, atol=1e-5, rtol=0)
    assert (path.image_ids == -1).all()
    r = cams.centers.norm(dim=-1)
    torch.testing.assert_close(path.centers.norm(dim=-1)[1::2], (r[:-1] + r[1:]) / 2, atol=1e-5, rtol=0)
    # the midpoint looks at the centre like its neighbours do (look_at cameras)
    fwd = path.forward[1]
    to_center = -path.centers[1] / path.centers[1].norm()
    assert float((fwd * to_center).sum()) > 0.999


def _cfg(tmp_path, **train):
    base = {"steps": 30, "log_every": 10, "checkpoint_every": 10, "progress": False,
            "losses": {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}},
            "optim": {"groups": {}}, "eval": {"lpips": False, "video_frames": 6}}
    base.update(train)
    return OmegaConf.create({"seed": 0, "device": "cpu", "dataset": {"kind": "tiny"},
                             "backbone": {"name": "_tiny_image"}, "act": {"enabled": True, "mode": "rgb", "lr": 1e-3},
                             "train": base})


def test_run_stage1_end_to_end_resume_and_reload(tmp_path):
    scene = tiny_scene()
    cfg = _cfg(tmp_path)
    out = run_stage1(cfg, scene, tmp_path)["stage1"]
    assert out["steps"] == 30 and out["steps_per_s"] > 0 and out["num_primitives"] == 16 * 24
    assert set(out["train"]) >= {"psnr", "ssim", "lpips", "psnr_masked"} and out["test"]["psnr"] > 10
    assert out["depth"]["test_mae"] == pytest.approx(float(out["depth"]["test_mae_pct"]) * scene.size / 100)
    assert out["lpips_weights"] == "skipped"
    assert out["metrics_convention"] == {"name": "3dgs", "quantise": True, "ssim": "3dgs", "lpips_net": "vgg"}
    assert (tmp_path / "checkpoints" / "last.pt").is_file()
    video = [p for p in tmp_path.iterdir() if p.name.startswith("turntable")]
    assert len(video) == 1 and video[0].stat().st_size > 0 and video[0].suffix == ".mp4"
    with open(tmp_path / "views.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["split"] for r in rows] == ["train"] * 4 + ["train_paper"] * 4 + ["test"] * 2
    assert out["protocols"]["train_paper"].startswith("each view with its own ACT")
    assert out["protocols"]["train"] == out["protocols"]["test"] == "the mean ACT, against the noise-free image"
    assert out["train_paper"]["psnr"] != out["train"]["psnr"]  # the observed images carry gain and noise
    train_psnr = [float(r["psnr"]) for r in rows if r["split"] == "train"]
    assert out["train"]["psnr"] == pytest.approx(sum(train_psnr) / 4, rel=1e-6)
    # the stage-1 model reloads and renders identically to what was evaluated
    bb, act = load_stage1(tmp_path / "checkpoints" / "last.pt", scene, cfg)
    assert act is not None
    again = run_stage1(cfg, scene, tmp_path)["stage1"]  # finished run: resumes at 30, trains nothing
    assert again["resumed_from"] == 30 and again["test"]["psnr"] == pytest.approx(out["test"]["psnr"])
    with torch.no_grad():
        ref = torch.sigmoid(bb.logits + bb.gain)
        img = bb.render(scene.test.cameras[:1])["rgb"][0]
    W, b = act.transforms(torch.tensor([-1]))
    torch.testing.assert_close(img, (W[0] * ref + b[0]).clamp(0, 1))
    with pytest.raises(TrainingError, match="train.steps"):
        run_stage1(_cfg(tmp_path, steps=40), scene, tmp_path)


def test_periodic_evaluation_reports_psnr_ssim_and_depth_error(tmp_path):
    scene = tiny_scene()
    cfg = _cfg(tmp_path, steps=30, eval_every=10,
               eval={"lpips": False, "renders": False, "video": False, "periodic_views": 1})
    out = run_stage1(cfg, scene, tmp_path)["stage1"]
    assert [e["step"] for e in out["periodic"]] == [10, 20]  # the final step has the full evaluation
    for e in out["periodic"]:
        assert set(e) == {"step", "test_psnr", "test_ssim", "test_depth_mae_pct"}
        assert math.isfinite(e["test_psnr"]) and e["test_depth_mae_pct"] >= 0


def test_lpips_on_the_held_out_views_only(tmp_path, monkeypatch):
    """``eval.lpips_splits=test`` (the demo's): LPIPS scores the test views and no training view; the training
    views' LPIPS is NaN, and metrics.json says why."""
    import arcsem.metrics as metrics_module
    from arcsem.metrics_json import strict_metrics

    calls = []
    monkeypatch.setattr(metrics_module, "lpips", lambda pred, gt, mask=None, **kw: (calls.append(mask) or 0.25, "ok"))
    scene = tiny_scene()
    cfg = _cfg(tmp_path, eval={"lpips": True, "lpips_splits": "test", "video": False, "renders": False})
    out = run_stage1(cfg, scene, tmp_path)["stage1"]
    assert len(calls) == 2 * len(scene.test)  # whole and masked, held-out views only
    assert out["test"]["lpips"] == 0.25 and math.isnan(out["train"]["lpips"]) and out["lpips_weights"] == "ok"
    nulls = strict_metrics({"stage1": out})["nulls"]
    assert "held-out views only" in nulls["stage1.train.lpips"]
    calls.clear()
    cfg = _cfg(tmp_path / "all", eval={"lpips": True, "video": False, "renders": False})  # the default: every view
    out = run_stage1(cfg, scene, tmp_path / "all")["stage1"]
    assert out["train"]["lpips"] == 0.25 and len(calls) == 2 * (2 * len(scene.train) + len(scene.test))
