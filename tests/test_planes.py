"""Shadow-volume planes: orientation, shared-edge exactness, inclusion vs a segment test."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings, strategies as st

from shadowlab.geometry.planes import in_shadow_volume, shadow_volume_planes, to_clip_space

_planes_jit = jax.jit(shadow_volume_planes)
coord = st.floats(-10, 10, allow_nan=False, allow_infinity=False, width=32)
point = st.tuples(coord, coord, coord)


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


@settings(max_examples=60, deadline=None)
@given(a=point, b=point, c=point, d=point, light=point)
def test_shared_edges_get_exactly_negated_planes(a, b, c, d, light):
    # Triangles (a, b, c) and (b, a, d) share edge ab, listed in opposite orders.
    tri = jnp.asarray(np.array([[a, b, c], [b, a, d]], np.float32))
    lh = jnp.asarray(np.array([*light, 1.0], np.float32))
    planes, valid = _planes_jit(tri, lh)
    planes = np.asarray(planes)
    if np.asarray(valid).all():
        c_side = np.asarray(c) @ planes[0, 0, :3] + planes[0, 0, 3]
        d_side = np.asarray(d) @ planes[0, 0, :3] + planes[0, 0, 3]
        if c_side * d_side < 0:    # third vertices on opposite sides: volumes are neighbours
            np.testing.assert_array_equal(planes[0, 0], -planes[1, 0])
        elif c_side * d_side > 0:
            np.testing.assert_array_equal(planes[0, 0], planes[1, 0])


def test_planes_are_oriented_and_inclusion_matches_segment_test():
    rng = np.random.default_rng(0)
    light = np.array([0.5, 8.0, -0.3])
    tris = rng.uniform(-2, 2, (40, 3, 3)) + [0, 3, 0]
    planes, valid = shadow_volume_planes(jnp.asarray(tris), jnp.asarray(np.append(light, 1.0)))
    planes = np.asarray(planes)
    assert np.asarray(valid).all()
    # interior of each triangle is inside its edge planes; the light is in front of the cap
    centroids = tris.mean(axis=1)
    assert np.all(np.einsum("tpi,ti->tp", planes[:, :3, :3], centroids) + planes[:, :3, 3] > 0)
    assert np.all(planes[:, 3, :3] @ light + planes[:, 3, 3] > 0)
    pts = rng.uniform(-6, 6, (400, 3)) * [1, 0.5, 1]
    for t in range(len(tris)):
        got = np.asarray(in_shadow_volume(jnp.asarray(planes[t]), jnp.asarray(pts), 0.0))
        want = np.array([_segment_hits_triangle(p, light, tris[t]) for p in pts])
        assert np.array_equal(got, want), t


def test_degenerate_and_edge_on_triangles_are_invalid():
    light = jnp.asarray([0.0, 10.0, 0.0, 1.0])
    tri = jnp.asarray(np.array([
        [[0, 0, 0], [1, 0, 0], [2, 0, 0]],        # collinear
        [[0, 0, 0], [0, 0, 0], [0, 0, 1]],        # repeated vertex
        [[0, 0, 0], [1, 0, 0], [0, 5, 0]],        # plane z = 0 contains the light
        [[0, 0, 0], [1, 0, 0], [0, 0, 1]],        # a proper triangle
    ], np.float32))
    _, valid = shadow_volume_planes(tri, light)
    assert np.asarray(valid).tolist() == [False, False, False, True]


def test_directional_light_volume_is_a_prism():
    tri = np.array([[[0, 1, 0], [1, 1, 0], [0, 1, 1]]], float)
    light = jnp.asarray([0.0, 1.0, 0.0, 0.0])          # light comes from +Y
    planes, valid = shadow_volume_planes(jnp.asarray(tri), light)
    pts = jnp.asarray([[0.2, -5, 0.2], [0.2, 0.5, 0.2], [0.9, -1, 0.9], [0.2, 2, 0.2]])
    assert np.asarray(in_shadow_volume(planes[0], pts, 1e-6)).tolist() == [True, True, False, False]


def test_clip_space_planes_keep_the_sign_of_distances():
    rng = np.random.default_rng(1)
    vp = rng.normal(size=(4, 4)) + 4 * np.eye(4)
    planes = rng.normal(size=(5, 4))
    pts = np.c_[rng.normal(size=(50, 3)), np.ones(50)]
    clip_pts = pts @ vp.T
    clip_planes = np.asarray(to_clip_space(jnp.asarray(planes), jnp.asarray(vp)))
    np.testing.assert_allclose(clip_pts @ clip_planes.T, pts @ planes.T, rtol=1e-6, atol=1e-6)


def test_jit_matches_eager():
    rng = np.random.default_rng(2)
    tri = jnp.asarray(rng.normal(size=(16, 3, 3)).astype(np.float32))
    light = jnp.asarray([1.0, 5.0, 2.0, 1.0], jnp.float32)
    eager = shadow_volume_planes(tri, light)
    jitted = jax.jit(shadow_volume_planes)(tri, light)
    np.testing.assert_allclose(np.asarray(eager[0]), np.asarray(jitted[0]), rtol=1e-6, atol=1e-6)
    assert np.array_equal(np.asarray(eager[1]), np.asarray(jitted[1]))
