"""The canonical triangle setup (``geometry.triangle_setup``), the one every exact method
runs: bit-equality with a plain per-triangle NumPy loop, orientation, shared-edge
exactness, inclusion against a segment test, validity."""

from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from shadowlab.core.capacity import bucket, pad
from shadowlab.geometry.triangle_setup import lex_less, shadow_volume_planes
from shadowlab.core.frame import precision_mode

coord = st.floats(-10, 10, allow_nan=False, allow_infinity=False, width=32)
point = st.tuples(coord, coord, coord)


def _setup(tri, light):
    """shadow_volume_planes as NumPy: planes [T, 4, 4], valid [T]."""
    planes, valid = shadow_volume_planes(jnp.asarray(tri), jnp.asarray(light))
    return np.asarray(planes).reshape(-1, 4, 4), np.asarray(valid)


def _loop_setup(tri, light):
    """The setup one triangle at a time with NumPy scalars of tri's dtype (each operation
    rounded once, nothing fused): planes [T, 4, 4], valid [T]."""
    dt = tri.dtype.type
    tol = dt(64) * dt(np.finfo(dt).eps)
    lxyz, lw = [dt(x) for x in light[:3]], dt(light[3])

    def dot(a, b):
        return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def sub(a, b):
        return [a[k] - b[k] for k in range(3)]

    def oriented(n, d, flip):
        if flip:
            n, d = [-x for x in n], -d
        length = np.sqrt(dot(n, n))
        safe = length if length > 0 else dt(1)
        return [n[0] / safe, n[1] / safe, n[2] / safe, d / safe], length

    planes = np.zeros((len(tri), 4, 4), dt)
    valid = np.zeros(len(tri), bool)
    for t in range(len(tri)):
        v = [[tri[t, i, k] for k in range(3)] for i in range(3)]
        ok = True
        for i in range(3):
            a, b, c = v[i], v[(i + 1) % 3], v[(i + 2) % 3]
            lo, hi = (b, a) if tuple(b) < tuple(a) else (a, b)
            n = cross(sub(hi, lo), [lxyz[k] - lw * lo[k] for k in range(3)])
            d = -dot(n, lo)
            side = dot(n, sub(c, lo))
            planes[t, i], length = oriented(n, d, side < 0)
            reach = max(np.sqrt(dot(sub(c, a), sub(c, a))), np.sqrt(dot(sub(c, b), sub(c, b))))
            ok &= bool(length > 0) and bool(abs(side) > (tol * length) * reach)
        cn = cross(sub(v[1], v[0]), sub(v[2], v[0]))
        cd = -dot(cn, v[0])
        to_light = [lxyz[k] - lw * v[0][k] for k in range(3)]
        light_side = dot(cn, to_light)
        planes[t, 3], length = oriented(cn, cd, light_side < 0)
        reach = np.sqrt(dot(to_light, to_light))
        ok &= bool(length > 0) and bool(abs(light_side) > (tol * length) * reach)
        valid[t] = ok
    return planes, valid


def _triangles(rng, n):
    """Random triangles [n, 3, 3] with shared edges, repeated and collinear vertices."""
    tri = rng.uniform(-2, 2, (n, 3, 3))
    tri[1::4, 0], tri[1::4, 1] = tri[0::4, 1], tri[0::4, 0]       # shared edges, reversed
    tri[2::8, 2] = tri[2::8, 1]                                   # repeated vertex
    tri[3::8, 2] = 2 * tri[3::8, 1] - tri[3::8, 0]                # collinear
    return tri


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("light", [[0.5, 8.0, -0.3, 1.0], [0.3, 1.0, 0.2, 0.0]])
def test_setup_equals_a_numpy_loop_at_every_padding(precision, light):
    rng = np.random.default_rng(7)
    with precision_mode(precision) as dt:
        tri = _triangles(rng, 96).astype(dt)
        lh = np.asarray(light, dt)
        want, want_ok = _loop_setup(tri, lh)
        assert 0 < want_ok.sum() < len(tri)
        for cap in (len(tri), bucket(len(tri), minimum=16), 1024):
            planes, valid = _setup(pad(tri, cap), lh)
            assert planes.dtype == dt
            np.testing.assert_array_equal(planes[: len(tri)], want)
            np.testing.assert_array_equal(valid[: len(tri)], want_ok)


def test_setup_rounds_the_same_inside_another_program():
    """Inlined into a bigger jitted program (where XLA could fuse its products into
    FMAs), the setup keeps its bits."""
    rng = np.random.default_rng(8)
    tri = jnp.asarray(rng.uniform(-3, 3, (200, 3, 3)).astype(np.float32))
    light = jnp.asarray([1.0, 5.0, 2.0, 1.0], jnp.float32)

    @jax.jit
    def fused(tri, light):
        planes, valid = shadow_volume_planes(tri * 1.0, light)
        return planes * 2.0 + 1.0, valid

    alone, ok = shadow_volume_planes(tri, light)
    inside, ok2 = fused(tri, light)
    np.testing.assert_array_equal(np.asarray(alone) * np.float32(2) + np.float32(1),
                                  np.asarray(inside))
    np.testing.assert_array_equal(np.asarray(ok), np.asarray(ok2))


def test_lex_less_is_tuple_order():
    rng = np.random.default_rng(9)
    a = rng.integers(-1, 2, (300, 3)).astype(np.float32)
    b = rng.integers(-1, 2, (300, 3)).astype(np.float32)
    got = np.asarray(lex_less(list(jnp.asarray(a).T), list(jnp.asarray(b).T)))
    assert got.tolist() == [tuple(x) < tuple(y) for x, y in zip(a, b)]


@settings(max_examples=60, deadline=None)
@given(a=point, b=point, c=point, d=point, light=point)
def test_shared_edges_get_exactly_negated_planes(a, b, c, d, light):
    # Triangles (a, b, c) and (b, a, d) share edge ab, listed in opposite orders.
    tri = np.array([[a, b, c], [b, a, d]], np.float32)
    planes, valid = _setup(tri, np.array([*light, 1.0], np.float32))
    if valid.all():
        c_side = np.asarray(c) @ planes[0, 0, :3] + planes[0, 0, 3]
        d_side = np.asarray(d) @ planes[0, 0, :3] + planes[0, 0, 3]
        if c_side * d_side < 0:    # third vertices on opposite sides: volumes are neighbours
            np.testing.assert_array_equal(planes[0, 0], -planes[1, 0])
        elif c_side * d_side > 0:
            np.testing.assert_array_equal(planes[0, 0], planes[1, 0])


def _segment_hits_triangle(p, light, tri):
    """Plain float64 loop: does the open segment p -> light cross triangle tri [3, 3]?"""
    d = light - p
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    h = np.cross(d, e2)
    a = e1 @ h
    if abs(a) < 1e-12:
        return False
    f = 1 / a
    s = p - tri[0]
    u = f * (s @ h)
    q = np.cross(s, e1)
    v = f * (d @ q)
    t = f * (e2 @ q)
    return u >= 0 and v >= 0 and u + v <= 1 and 1e-9 < t < 1 - 1e-9


def _inside(planes, pts, cap_bias):
    """bool [P]: pts [P, 3] inside all three edge planes and more than cap_bias behind
    the cap of one volume planes [4, 4]."""
    dist = pts @ planes[:, :3].T + planes[:, 3]
    return np.all(dist[:, :3] >= 0, axis=1) & (dist[:, 3] < -cap_bias)


def test_planes_are_oriented_and_inclusion_matches_segment_test():
    rng = np.random.default_rng(0)
    light = np.array([0.5, 8.0, -0.3])
    tris = rng.uniform(-2, 2, (40, 3, 3)) + [0, 3, 0]
    with precision_mode("float64"):
        planes, valid = _setup(tris, np.append(light, 1.0))
    assert valid.all()
    # interior of each triangle is inside its edge planes; the light is in front of the cap
    centroids = tris.mean(axis=1)
    assert np.all(np.einsum("tpi,ti->tp", planes[:, :3, :3], centroids) + planes[:, :3, 3] > 0)
    assert np.all(planes[:, 3, :3] @ light + planes[:, 3, 3] > 0)
    pts = rng.uniform(-6, 6, (400, 3)) * [1, 0.5, 1]
    for t in range(len(tris)):
        want = np.array([_segment_hits_triangle(p, light, tris[t]) for p in pts])
        assert np.array_equal(_inside(planes[t], pts, 0.0), want), t


def test_degenerate_and_edge_on_triangles_are_invalid():
    tri = np.array([
        [[0, 0, 0], [1, 0, 0], [2, 0, 0]],        # collinear
        [[0, 0, 0], [0, 0, 0], [0, 0, 1]],        # repeated vertex
        [[0, 0, 0], [1, 0, 0], [0, 5, 0]],        # plane z = 0 contains the light
        [[0, 0, 0], [1, 0, 0], [0, 0, 1]],        # a proper triangle
    ], np.float32)
    _, valid = _setup(tri, np.array([0.0, 10.0, 0.0, 1.0], np.float32))
    assert valid.tolist() == [False, False, False, True]


def _exact_orientation(a, b, c, d):
    """Sign of det(b - a, c - a, d - a) for float corners [3], in exact rational
    arithmetic (no rounding at all)."""
    a, b, c, d = ([Fraction(float(x)) for x in p] for p in (a, b, c, d))
    u, v, w = ([p[k] - a[k] for k in range(3)] for p in (b, c, d))
    det = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
           + u[2] * (v[0] * w[1] - v[1] * w[0]))
    return (det > 0) - (det < 0)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_valid_volumes_are_oriented_by_the_exact_sign_far_from_the_origin(precision):
    """Small nearly collinear triangles hundreds of units from the origin (the local
    coordinates of a scene far from the world origin): a triangle the setup calls valid
    has its three edge planes and its cap oriented by the exact orientation of its
    rounded corners and the light. Forming the orientation as n . c + d cancelled terms
    of size |n| |corner|, so such slivers passed the degeneracy test with planes of both
    orientations, and their "volume" was a half-space (found on `soup` far from the
    origin: 356 of 2,160 pixels shadowed by one such triangle in float32)."""
    rng = np.random.default_rng(11)
    n = 1500
    with precision_mode(precision) as dt:
        eps = float(np.finfo(dt).eps)
        centre = rng.uniform(100, 300, (n, 1, 3)) * rng.choice([-1, 1], (n, 1, 3))
        axis = rng.normal(size=(n, 1, 3))
        # off the line by 1e-2 to 1e4 of the corners' rounding
        off = rng.normal(size=(n, 1, 3)) * (300 * eps) * 10.0 ** rng.uniform(-2, 4, (n, 1, 1))
        t = np.sort(rng.uniform(-1, 1, (n, 3, 1)), axis=1)
        tri = (centre + t * axis + np.array([0.0, 1.0, 0.0])[:, None] * off).astype(dt)
        light = np.array([*(centre[0, 0] + [80.0, 60.0, -40.0]), 1.0]).astype(dt)
        planes, valid = _setup(tri, light)
    v, lp = tri.astype(np.float64), light[:3].astype(np.float64)
    for k in np.flatnonzero(valid):
        for i in range(3):
            a, b, c = v[k, i], v[k, (i + 1) % 3], v[k, (i + 2) % 3]
            lo, hi = (b, a) if tuple(b) < tuple(a) else (a, b)
            normal = np.cross(hi - lo, lp - lo)        # a direction: rounding is harmless
            assert np.sign(normal @ planes[k, i, :3]) == _exact_orientation(lo, hi, lp, c), (k, i)
        cn = np.cross(v[k, 1] - v[k, 0], v[k, 2] - v[k, 0])
        assert np.sign(cn @ planes[k, 3, :3]) == _exact_orientation(*v[k], lp), k
    assert 0 < valid.sum() < n

def test_directional_light_volume_is_a_prism():
    tri = np.array([[[0, 1, 0], [1, 1, 0], [0, 1, 1]]], np.float32)
    planes, valid = _setup(tri, np.array([0.0, 1.0, 0.0, 0.0], np.float32))  # from +Y
    assert valid.all()
    pts = np.array([[0.2, -5, 0.2], [0.2, 0.5, 0.2], [0.9, -1, 0.9], [0.2, 2, 0.2]])
    assert _inside(planes[0], pts, 1e-6).tolist() == [True, True, False, False]
