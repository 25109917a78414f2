"""The synthetic scene's optional surface texture: a view-consistent gain, off by default (scene unchanged)."""
from __future__ import annotations

import torch

from arcsem.synthetic import SceneParams
from arcsem.synthetic.cache import scene_key
from arcsem.synthetic.texture import texture_gain, value_noise


def test_value_noise_is_smooth_bounded_and_deterministic():
    gen = torch.Generator().manual_seed(0)
    p = torch.rand(2000, 3, generator=gen, dtype=torch.float64) * 20 - 10
    n = value_noise(p, seed=3)
    assert n.min() >= 0 and n.max() <= 1 and n.std() > 0.1, "uniform lattice values blended: spread over [0, 1]"
    assert torch.equal(n, value_noise(p.clone(), seed=3)), "same points, same seed: same values"
    assert not torch.allclose(n, value_noise(p, seed=4)), "the seed changes the pattern"
    step = value_noise(p + 1e-4, seed=3) - n
    assert step.abs().max() < 1e-3, "continuous: a 1e-4 move changes the noise by < 1e-3 (slope <= ~4.5 per axis)"
    corner = torch.tensor([[2.0, -3.0, 5.0]], dtype=torch.float64)
    assert abs(float(value_noise(corner, 3)[0]) - float(value_noise(corner + 1e-9, 3)[0])) < 1e-6, "exact at nodes"


def test_texture_gain_amplitude_and_off_switch():
    p = torch.rand(5000, 3, generator=torch.Generator().manual_seed(1)) * 4 - 2
    assert torch.equal(texture_gain(p, 0.0, 0.1, 0), torch.ones(5000)), "amplitude 0: exactly the untextured scene"
    g = texture_gain(p, 0.3, 0.1, 0)
    assert g.dtype == torch.float32 and g.min() >= 0.7 - 1e-6 and g.max() <= 1.3 + 1e-6
    assert abs(float(g.mean()) - 1.0) < 0.05 and float(g.std()) > 0.03, "a gain around 1 that varies"


def test_untextured_scene_keeps_its_cache_key_and_textured_differs():
    base = SceneParams()
    assert scene_key(SceneParams(texture=0.0, texture_scale=0.5)) == scene_key(base), \
        "texture 0: the scale is irrelevant and the cache folder of the built-in scene is unchanged"
    assert scene_key(SceneParams(texture=0.3)) != scene_key(base)
    assert scene_key(SceneParams(texture=0.3)) != scene_key(SceneParams(texture=0.3, texture_scale=0.1))
