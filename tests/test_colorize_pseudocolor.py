"""Pseudo-colours on an analytic ellipsoid: known colours, radius semantics vs brute force, disk cache."""
import torch

from arcsem.colorize.analytic import arc_cameras, ellipsoid_depth, point_color
from arcsem.colorize.pseudocolor import (
    cached_pseudo_colors,
    masked_points,
    pixel_footprint,
    pseudo_colors,
    pseudo_key,
)


def _scene(model="pinhole", n=6, w=64, h=48):
    cams = arc_cameras(n, w, h, model=model)
    depth = ellipsoid_depth(cams)
    pts = cams.unproject(depth)
    return cams, depth, depth > 0, point_color(pts.double()).float()


def test_pixel_footprint_models():
    cams = arc_cameras(2, 64, 48, "pinhole")
    z = torch.tensor([[2.0, 4.0], [1.0, 1.0]])
    fx = cams.K[0, 0, 0]
    torch.testing.assert_close(pixel_footprint(cams, z), z / fx)
    ortho = arc_cameras(2, 64, 48, "orthographic")
    torch.testing.assert_close(pixel_footprint(ortho, z), torch.full_like(z, 1 / float(ortho.K[0, 0, 0])))


def test_pseudo_colors_match_the_surface_colour():
    for model in ("pinhole", "orthographic"):
        cams, depth, mask, gt = _scene(model)
        ref = [0, 2, 5]
        colors, valid = pseudo_colors(cams, depth, mask, ref, gt[ref], progress=False)
        assert torch.equal(valid[ref], mask[ref]) and torch.equal(colors[0][mask[0]], gt[0][mask[0]])
        # the middle view (between references 0 and 2) is almost fully covered
        assert valid[1].sum() > 0.95 * mask[1].sum()
        # colours differ from the truth by at most the colour change over the search radius
        err = (colors - gt).abs().amax(-1)[valid]
        assert err.max() < 0.05, (model, float(err.max()))
        assert not valid[~mask].any() and (colors[~valid] == 0).all()


def test_radius_is_respected_against_brute_force():
    cams, depth, mask, gt = _scene(n=5, w=40, h=30)
    ref, radius = [0], 0.03
    colors, valid = pseudo_colors(cams, depth, mask, ref, gt[ref], radius=radius, progress=False)
    _, rp = masked_points(cams[0], depth[0], mask[0])
    rc = gt[0].reshape(-1, 3)[mask[0].reshape(-1)]
    for v in range(1, 5):
        flat, q = masked_points(cams[v], depth[v], mask[v])
        d = torch.cdist(q, rp)
        dmin, arg = d.min(1)
        inside = dmin <= radius
        got = valid[v].reshape(-1)[flat]
        assert torch.equal(got, inside), v  # valid exactly where a reference point lies within the radius
        assert (~inside).any() and inside.any()  # both cases occur (view 4 sees parts view 0 does not)
        torch.testing.assert_close(colors[v].reshape(-1, 3)[flat][inside], rc[arg[inside]])


def test_cache_hit_and_miss_on_changed_reference(tmp_path):
    cams, depth, mask, gt = _scene(n=4, w=32, h=24)
    calls = []

    def run(refs):
        key = pseudo_key(depth, refs, ["a"], None, 2.0, mask, cams)

        def compute():
            calls.append(1)
            return pseudo_colors(cams, depth, mask, [0], refs, progress=False)

        return cached_pseudo_colors(tmp_path, key, compute)

    c1, v1, hit1 = run(gt[:1])
    c2, v2, hit2 = run(gt[:1])
    assert (hit1, hit2) == (False, True) and len(calls) == 1
    assert torch.equal(c1, c2) and torch.equal(v1, v2)
    changed = gt[:1].clone()
    changed[0, 10, 10] = 0.123
    _, _, hit3 = run(changed)
    assert not hit3 and len(calls) == 2
    assert not list(tmp_path.glob("*.tmp"))  # atomic writes leave no temporaries
