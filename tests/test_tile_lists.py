"""Per-tile lists against a NumPy brute force of the cone test over all tile x blocker pairs.

The reference re-implements the capsule test of ``structures.cones`` in NumPy (float64)
and evaluates it on every (tile, group) and (tile, triangle) pair; the lists must hold
exactly the surviving triangles, in tile order and group-major, member-minor order,
with the same depth-half bits. A list longer than the capacity is always flagged and
counted, whether it is truncated or evaluated in full.
"""

import math

import numpy as np
import pytest

from shadowlab.core.frame import precision_mode
from shadowlab.scene.view import SphereLight
from shadowlab.structures import cones as cn
from shadowlab.structures import tile_lists as tl
from shadowlab.core.timing import StageTimer


def _np_cone_hits(cone, s0, s1, r0, r1):
    """NumPy twin of ``cones.cone_hits_capsule``: cone arrays [..., ...] broadcast
    against the capsules; returns bool of the broadcast shape."""
    apex, axis, sa, ca = cone["apex"], cone["axis"], cone["sin"], cone["cos"]
    ds = s1 - s0

    def dist(p):
        v = p - apex
        h = v[..., 0] * axis[..., 0] + v[..., 1] * axis[..., 1] + v[..., 2] * axis[..., 2]
        vv = v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2]
        q = np.sqrt(np.maximum(vv - h * h, 0.0))
        side = q * ca - h * sa
        return np.where(side <= 0, 0.0, np.where(h * ca + q * sa >= 0, side, np.sqrt(vv)))

    def f(t):
        return dist(s0 + t[..., None] * ds) - (r0 + t * (r1 - r0))

    shape = np.broadcast_shapes(r0.shape, sa.shape)
    lo, hi = np.zeros(shape), np.ones(shape)
    g = (math.sqrt(5) - 1) / 2
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(cn.GOLDEN_ITERS):
        left = fa <= fb
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
        x = np.where(left, hi - g * (hi - lo), lo + g * (hi - lo))
        fx = f(x)
        a, b, fa, fb = (np.where(left, x, b), np.where(left, a, x), np.where(left, fx, fb),
                        np.where(left, fa, fx))
    t = 0.5 * (lo + hi)
    lip = np.sqrt((ds ** 2).sum(-1)) + np.abs(r1 - r0)
    best = np.minimum(np.minimum(f(t), f(np.zeros_like(t))), f(np.ones_like(t)))
    meets = best - lip * (hi - lo) <= 0
    reach = np.maximum((s0 * axis).sum(-1) + r0, (s1 * axis).sum(-1) + r1)
    return (meets & (reach >= cone["t0"])) | cone["always"]


def _scene(light_kind, seed=1):
    rng = np.random.default_rng(seed)
    n_tri, n_tiles, k = 240, 30, 16
    base = rng.uniform([0, 2, 0], [10, 4, 10], (n_tri, 1, 3))
    tri = base + rng.normal(0, 0.25, (n_tri, 3, 3))
    members = np.full((-(-n_tri // k), k), -1)
    members.reshape(-1)[:n_tri] = rng.permutation(n_tri)
    members[2, 5:] = -1                                      # a partly empty group
    bounds = np.zeros((n_tiles, 2, 8))
    for h in range(2):
        s0 = rng.uniform([0, -1, 0], [10, 0.5, 10], (n_tiles, 3))
        bounds[:, h, 0:3] = s0
        bounds[:, h, 4:7] = s0 + rng.normal(0, 0.6, (n_tiles, 3))
        bounds[:, h, 3] = rng.uniform(0.1, 0.8, n_tiles)
        bounds[:, h, 7] = rng.uniform(0.1, 0.8, n_tiles)
    bounds[::4, 1, 3] = -1                                   # empty far halves
    active = rng.random(n_tiles) < 0.85
    if light_kind == "sun":
        light = SphereLight(direction=(0.3, -1.0, 0.2), angular_radius_deg=4.0)
    else:
        light = SphereLight(position=(5.0, 12.0, 5.0), radius=1.5)
    return tri, members, bounds, active, light


def _brute_force(tri, members, bounds, active, light, settings):
    """Reference lists: for every active tile, every group in order, every member."""
    tri_c = cn.blocker_cones(tri, None, light)
    grp_c = cn.blocker_cones(tri, members, light)
    halves = settings.halves

    def hits(cone):                     # bool [tiles, n, 2] on every pair
        out = np.zeros((len(bounds), len(cone["t0"]), 2), bool)
        c = {k: v[None] for k, v in cone.items()}
        for h in range(halves):
            b = bounds[:, h][:, None]
            out[..., h] = _np_cone_hits(c, b[..., 0:3], b[..., 4:7], b[..., 3], b[..., 7]) \
                & (b[..., 3] >= 0)
        return out

    tri_hit, grp_hit = hits(tri_c), hits(grp_c)
    rows = []
    for t in np.flatnonzero(active):
        for g in range(len(members)):
            if settings.tile_cull and settings.cluster_cull:
                gh = grp_hit[t, g]
                if not gh.any():
                    continue
            else:
                gh = np.ones(2, bool)
            for m in members[g]:
                if m < 0:
                    continue
                th = tri_hit[t, m] & gh if settings.tile_cull else gh
                if th.any():
                    rows.append((t, m, int(th[0]) | int(th[1]) << 1))
    return np.array(rows, np.int64).reshape(-1, 3)


def _settings(**kw):
    base = dict(face_cull="front", gather_cull=True, tile_cull=True, cluster_cull=True,
                cluster_size=16, bound="capsule", half_z=True, capacity=2048,
                on_overflow="truncate")
    return tl.CullSettings(**{**base, **kw})


def _build(tri, members, bounds, active, light, settings):
    with precision_mode("float64") as dtype:
        return tl.build_tile_lists(
            StageTimer(), cn.pad_cones(cn.blocker_cones(tri, members, light)),
            cn.pad_cones(cn.blocker_cones(tri, None, light)), members, bounds, active,
            settings, dtype)


@pytest.mark.parametrize("light_kind", ["sun", "sphere"])
@pytest.mark.parametrize("cull", [dict(), dict(cluster_cull=False), dict(half_z=False),
                                  dict(tile_cull=False, cluster_cull=False)])
def test_lists_equal_brute_force(light_kind, cull):
    tri, members, bounds, active, light = _scene(light_kind)
    settings = _settings(**cull)
    got = _build(tri, members, bounds, active, light, settings)
    want = _brute_force(tri, members, bounds, active, light, settings)
    assert 0 < len(want) < (members >= 0).sum() * active.sum() or not settings.tile_cull
    np.testing.assert_array_equal(got.tile, want[:, 0])
    np.testing.assert_array_equal(got.entry, want[:, 1])
    np.testing.assert_array_equal(got.half_bits, want[:, 2])
    lengths = np.bincount(want[:, 0], minlength=len(active))
    np.testing.assert_array_equal(got.lengths, lengths)
    np.testing.assert_array_equal(got.starts, np.concatenate([[0], np.cumsum(lengths)[:-1]]))
    assert not got.lengths[~active].any()
    assert got.cluster_pairs == active.sum() * len(members)
    assert got.triangle_pairs >= len(want)
    assert not got.overflow.any() and got.dropped_entries == 0


@pytest.mark.parametrize("on_overflow", ["truncate", "full"])
def test_capacity_overflow_is_flagged_and_counted(on_overflow):
    tri, members, bounds, active, light = _scene("sun")
    cap = 4
    got = _build(tri, members, bounds, active, light,
                 _settings(capacity=cap, on_overflow=on_overflow))
    full = _brute_force(tri, members, bounds, active, light, _settings())
    lengths = np.bincount(full[:, 0], minlength=len(active))
    assert (lengths > cap).sum() >= 3                       # some lists really overflow
    np.testing.assert_array_equal(got.lengths, lengths)     # lists are never cut
    np.testing.assert_array_equal(got.overflow, lengths > cap)
    assert got.overflow_tiles == (lengths > cap).sum()
    if on_overflow == "truncate":
        np.testing.assert_array_equal(got.counts, np.minimum(lengths, cap))
        assert got.dropped_entries == (lengths - np.minimum(lengths, cap)).sum() > 0
    else:
        np.testing.assert_array_equal(got.counts, lengths)
        assert got.dropped_entries == 0


def test_settings_refuse_bad_values():
    with pytest.raises(ValueError, match="on_overflow"):
        _settings(on_overflow="drop")
    with pytest.raises(ValueError, match="capacity"):
        _settings(capacity=0)


def test_no_groups_give_no_cones():
    """Light-facing culling can remove every triangle (a one-sided occluder facing the
    light): zero groups give zero cones, not a reshape error."""
    tri = np.zeros((4, 3, 3))
    for light in (SphereLight(direction=(0, -1, 0), angular_radius_deg=1.0),
                  SphereLight(position=(0, 10, 0), radius=1.0)):
        cone = cn.blocker_cones(tri, np.zeros((0, 64), np.int64), light)
        assert all(len(v) == 0 for v in cone.values())
