"""SH basis against scipy's complex spherical harmonics, orthonormality, and the DC helpers."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from arcsem.backbones.sh import C0, RGB2SH, SH2RGB, eval_sh, sh_basis
from scipy.special import sph_harm_y


def scipy_real_sh(l: int, m: int, dirs: np.ndarray) -> np.ndarray:
    """Real SH with the Condon-Shortley phase kept (the 3DGS convention), from scipy's complex Y."""
    x, y, z = dirs.T
    theta = np.arccos(np.clip(z, -1, 1))  # polar
    phi = np.arctan2(y, x)  # azimuth
    Y = sph_harm_y(l, abs(m), theta, phi)
    if m < 0:
        return np.sqrt(2) * Y.imag
    if m > 0:
        return np.sqrt(2) * Y.real
    return Y.real


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_basis_matches_scipy_every_function():
    dirs = random_dirs(500)
    ours = sh_basis(3, torch.from_numpy(dirs)).numpy()
    for l in range(4):
        for m in range(-l, l + 1):
            ref = scipy_real_sh(l, m, dirs)
            np.testing.assert_allclose(ours[:, l * l + l + m], ref, atol=1e-12, err_msg=f"l={l} m={m}")


def test_basis_is_orthonormal_on_the_sphere():
    # Gauss-Legendre in cos(theta) x uniform in phi integrates degree <= 6 polynomials exactly.
    nodes, weights = np.polynomial.legendre.leggauss(12)
    phi = np.arange(24) * 2 * np.pi / 24
    ct, ph = np.meshgrid(nodes, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    w = (weights[:, None] * np.full_like(ph, 2 * np.pi / 24)).reshape(-1)
    B = sh_basis(3, torch.from_numpy(dirs)).numpy()
    gram = (B * w[:, None]).T @ B
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


def test_known_values_and_lower_degrees_ignore_higher_coefficients():
    d = torch.tensor([[0.0, 0.0, 2.0]], dtype=torch.float64)  # +z, not unit: normalised inside
    B = sh_basis(3, d)[0]
    assert B[0] == pytest.approx(0.28209479177387814)
    assert B[2] == pytest.approx(0.4886025119029199)  # Y_1,0 = C1 z
    assert B[6] == pytest.approx(0.31539156525252005 * 2)  # Y_2,0 = C2 (2z^2 - x^2 - y^2)
    assert B[12] == pytest.approx(0.3731763325901154 * 2)  # Y_3,0
    coeffs = torch.randn(5, 16, 3, dtype=torch.float64)
    dirs = torch.randn(5, 3, dtype=torch.float64)
    c0 = eval_sh(0, coeffs, dirs)
    torch.testing.assert_close(c0, coeffs[:, 0] * C0)
    coeffs2 = coeffs.clone()
    coeffs2[:, 4:] = 123.0  # beyond degree 1
    torch.testing.assert_close(eval_sh(1, coeffs2, dirs), eval_sh(1, coeffs, dirs))
    full = (sh_basis(3, dirs)[..., None] * coeffs).sum(1)
    torch.testing.assert_close(eval_sh(3, coeffs, dirs), full)


def test_broadcast_camera_batch_and_errors():
    coeffs = torch.randn(7, 16, 3)
    dirs = torch.randn(2, 7, 3)
    out = eval_sh(3, coeffs[None], dirs)
    assert out.shape == (2, 7, 3)
    torch.testing.assert_close(out[1], eval_sh(3, coeffs, dirs[1]))
    with pytest.raises(ValueError):
        eval_sh(2, torch.randn(7, 4, 3), dirs)


def test_rgb_sh_round_trip():
    rgb = torch.rand(10, 3, dtype=torch.float64)
    torch.testing.assert_close(SH2RGB(RGB2SH(rgb)), rgb)
    assert RGB2SH(torch.tensor(0.5)) == 0


def test_old_import_path_warns_and_gives_the_same_objects():
    """``arcsem.backbones.gaussians.sh`` (before issue 41) still works for plugin authors, with a DeprecationWarning."""
    import arcsem.backbones.gaussians.sh as old
    from arcsem.backbones import sh

    with pytest.warns(DeprecationWarning, match=r"gaussians\.sh\.eval_sh moved to arcsem\.backbones\.sh\.eval_sh"):
        assert old.eval_sh is sh.eval_sh
    with pytest.warns(DeprecationWarning, match="C0 moved"):
        from arcsem.backbones.gaussians.sh import C0 as old_c0
    assert old_c0 == sh.C0
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        old.nope  # noqa: B018
