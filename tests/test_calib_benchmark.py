"""benchmarks/calib_training.py: the similarity that carries the scene's points into a calibrated frame."""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from arcsem.calib.geometry import rodrigues

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    sys.path.insert(0, str(ROOT / "benchmarks"))  # as when run as a script: calib_synthetic beside it
    spec = importlib.util.spec_from_file_location("calib_training", ROOT / "benchmarks" / "calib_training.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write(folder: Path, R: np.ndarray, c: np.ndarray, fl: float, model: str) -> None:
    """transforms.json of world->camera rotations ``R [V, 3, 3]`` (OpenCV axes) and centres ``c [V, 3]``."""
    frames = []
    for i, (Ri, ci) in enumerate(zip(R, c)):
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = Ri.T, ci
        frames.append({"file_path": f"images/v{i}.png", "fl_x": fl,
                       "transform_matrix": (c2w @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()})
    folder.mkdir()
    (folder / "transforms.json").write_text(json.dumps({"camera_model": model, "frames": frames}))


@pytest.mark.parametrize("model", ["ORTHOGRAPHIC", "PINHOLE"])
def test_frame_similarity_recovers_the_map_between_two_camera_sets(tmp_path, model):
    rng = np.random.default_rng(1)
    V = 8
    R = rodrigues(rng.normal(0, 0.6, (V, 3)))
    c = -60.0 * R[:, 2, :] + rng.normal(0, 0.5, (V, 3))            # cameras looking at the origin
    Q, d = rodrigues(np.array([[0.1, -0.3, 0.7]]))[0], np.array([0.4, -1.2, 2.0])
    s = 1.0 if model == "ORTHOGRAPHIC" else 0.8                     # orthographic: the scale is the pixels' ratio
    fl_t, fl_c = 100.0, 100.0 / s
    # X_cal = s Q X_true + d: rotations R Q^T, centres s Q c + d (orthographic: any point on the ray will do)
    c_cal = s * c @ Q.T + d + (rng.normal(0, 5.0, (V, 1)) * (R @ Q.T)[:, 2, :] if model == "ORTHOGRAPHIC" else 0)
    _write(tmp_path / "true", R, c, fl_t, model)
    _write(tmp_path / "cal", R @ Q.T, c_cal, fl_c, model)
    s_fit, Q_fit, d_fit = _bench().frame_similarity(tmp_path / "true", tmp_path / "cal")
    assert s_fit == pytest.approx(s, rel=1e-9)
    np.testing.assert_allclose(Q_fit, Q, atol=1e-9)
    np.testing.assert_allclose(d_fit, d, atol=1e-7)
