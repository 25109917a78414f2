"""Orbit cameras around the specimen: frame from the training cameras, angles, looking at the centre,
full turns without a repeated frame, orthographic framing equal to the pinhole's at the centre."""
from __future__ import annotations

import pytest
import torch

from arcsem.cameras import Cameras, look_at
from arcsem.errors import ConfigError
from arcsem.orbit import OrbitConfig, camera_angles, orbit_cameras, orbit_frame


def arc_cameras(model: str = "pinhole", dist: float = 30.0) -> Cameras:
    """Cameras on an arc in front of the origin (world z up), looking at it: azimuth -40..40 at 10 deg."""
    az = torch.deg2rad(torch.linspace(-40, 40, 9, dtype=torch.float64))
    el = torch.deg2rad(torch.tensor(10.0, dtype=torch.float64))
    d = torch.stack([torch.sin(az) * torch.cos(el), -torch.cos(az) * torch.cos(el), torch.sin(el).expand_as(az)], -1)
    w2c = look_at(d * dist, torch.zeros_like(d), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    f = 2000.0 if model == "pinhole" else 60.0
    K = torch.tensor([[f, 0, 48], [0, f, 32], [0, 0, 1]], dtype=torch.float64).expand(9, 3, 3).clone()
    return Cameras(w2c, K, 96, 64, model)


BOUNDS = torch.tensor([[-1.0, -1.0, -0.8], [1.0, 1.0, 0.8]])


def test_frame_and_angles_of_the_training_cameras():
    cams = arc_cameras()
    frame = orbit_frame(cams, BOUNDS)
    torch.testing.assert_close(frame.up, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-9, rtol=0)
    torch.testing.assert_close(frame.front, torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64), atol=1e-9, rtol=0)
    assert frame.radius == pytest.approx(30.0)
    az, el = camera_angles(cams, frame)
    torch.testing.assert_close(az, torch.linspace(-40, 40, 9, dtype=torch.float64), atol=1e-6, rtol=0)
    torch.testing.assert_close(el, torch.full((9,), 10.0, dtype=torch.float64), atol=1e-6, rtol=0)


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_orbit_looks_at_the_centre_from_the_asked_angles(model):
    cams = arc_cameras(model)
    orbit = orbit_cameras(cams, BOUNDS, OrbitConfig(frames=8, elevation=35.0, width=48))
    assert len(orbit) == 8 and (orbit.width, orbit.height) == (48, 32) and orbit.model == model
    assert (orbit.image_ids == -1).all()
    uv, _ = orbit.project(torch.zeros(1, 3))
    torch.testing.assert_close(uv[:, 0], torch.tensor([[24.0, 16.0]]).expand(8, 2), atol=1e-3, rtol=0)
    az, el = camera_angles(orbit, orbit_frame(cams, BOUNDS))
    torch.testing.assert_close(el.float(), torch.full((8,), 35.0), atol=1e-4, rtol=0)
    torch.testing.assert_close(torch.remainder(az.float(), 360), torch.arange(8) * 45.0, atol=1e-3, rtol=0)
    # the same pixel footprint at the centre as the (half-width) training cameras
    if model == "pinhole":
        assert float(orbit.K[0, 0, 0]) == pytest.approx(1000.0)
    else:
        assert float(orbit.K[0, 0, 0]) == pytest.approx(30.0)


def test_model_switch_keeps_the_footprint():
    cams = arc_cameras("pinhole")
    ortho = orbit_cameras(cams, BOUNDS, OrbitConfig(frames=2, camera="orthographic", azimuth=(-10, 10)))
    assert ortho.model == "orthographic" and float(ortho.K[0, 0, 0]) == pytest.approx(2000.0 / 30.0)
    az, _ = camera_angles(ortho, orbit_frame(cams, BOUNDS))
    torch.testing.assert_close(az.float(), torch.tensor([-10.0, 10.0]), atol=1e-4, rtol=0)  # open range: ends kept


@pytest.mark.parametrize("bad", [{"frames": 0}, {"elevation": 95.0}, {"camera": "fisheye"}, {"width": 3},
                                 {"zoom": 0.0}])
def test_bad_orbits_are_config_errors(bad):
    with pytest.raises(ConfigError, match="orbit"):
        orbit_cameras(arc_cameras(), BOUNDS, OrbitConfig(**bad))
