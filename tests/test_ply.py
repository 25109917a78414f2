"""PLY export/import: exact round trip, the official byte layout, 2DGS scales, bad files."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from arcsem.backbones.gaussians.ply import ply_properties, read_ply, write_ply

from arcsem.errors import DataError


def params(n: int = 7, s: int = 3, rest: int = 15) -> dict:
    g = torch.Generator().manual_seed(0)
    return {
        "means": torch.randn(n, 3, generator=g), "quats": torch.randn(n, 4, generator=g),
        "log_scales": torch.randn(n, s, generator=g), "opacity_logits": torch.randn(n, generator=g),
        "sh_dc": torch.randn(n, 1, 3, generator=g), "sh_rest": torch.randn(n, rest, 3, generator=g),
    }


@pytest.mark.parametrize("s,rest", [(3, 15), (2, 15), (3, 0), (3, 8)])
def test_round_trip_exact(tmp_path, s, rest):
    p = params(s=s, rest=rest)
    write_ply(tmp_path / "g.ply", p)
    q = read_ply(tmp_path / "g.ply")
    assert set(q) == set(p)
    for k in p:
        assert torch.equal(q[k], p[k]), k


def test_layout_is_the_official_one(tmp_path):
    p = params(n=2)
    write_ply(tmp_path / "g.ply", p)
    raw = (tmp_path / "g.ply").read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 2"]
    names = [ln.split()[2] for ln in lines[3:]]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert names[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == ply_properties(15, 3) and len(names) == 62
    vals = np.frombuffer(body, dtype="<f4").reshape(2, 62)
    # channel-major f_rest: f_rest_{c*15+k} = coefficient k+1 of channel c
    assert vals[1, 9 + 15 * 2 + 4] == np.float32(p["sh_rest"][1, 4, 2])
    assert vals[0, 6 + 1] == np.float32(p["sh_dc"][0, 0, 1])
    assert vals[0, 54] == np.float32(p["opacity_logits"][0]) and (vals[:, 3:6] == 0).all()


def test_reads_double_and_big_endian(tmp_path):
    names = ply_properties(0, 3)
    rng = np.random.default_rng(0)
    data = rng.normal(size=(3, len(names)))
    head = "ply\nformat binary_big_endian 1.0\nelement vertex 3\n"
    head += "".join(f"property double {n}\n" for n in names) + "end_header\n"
    (tmp_path / "b.ply").write_bytes(head.encode() + data.astype(">f8").tobytes())
    q = read_ply(tmp_path / "b.ply")
    np.testing.assert_allclose(q["means"].numpy(), data[:, :3].astype(np.float32))
    np.testing.assert_allclose(q["quats"].numpy(), data[:, -4:].astype(np.float32))
    assert q["sh_rest"].shape == (3, 0, 3)


def test_bad_files(tmp_path):
    with pytest.raises(DataError, match="no such"):
        read_ply(tmp_path / "missing.ply")
    (tmp_path / "t.ply").write_bytes(b"not a ply\n")
    with pytest.raises(DataError, match="not a PLY"):
        read_ply(tmp_path / "t.ply")
    write_ply(tmp_path / "c.ply", params(n=4))
    raw = (tmp_path / "c.ply").read_bytes()
    (tmp_path / "c.ply").write_bytes(raw[:-10])
    with pytest.raises(DataError, match="truncated"):
        read_ply(tmp_path / "c.ply")
