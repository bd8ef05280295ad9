"""Shadow-volume planes of triangles (traced JAX; float32 or float64).

A triangle's shadow volume from a light is bounded by three *edge planes* (each
through one edge and the light) and its *cap* (the triangle's own plane). Planes are
``(nx, ny, nz, d)`` with unit normals, so ``dot(n, p) + d`` is a signed distance in
world units. Orientation: edge planes are non-negative on the triangle's side; the
cap is positive on the light's side.

Edge planes are computed from the edge's endpoints in lexicographic order of their
coordinates, so two triangles sharing an edge evaluate bit-identical expressions and
get exactly negated planes (polygon soup: vertices are compared by value, not index).
A point exactly on a shared edge plane is then inside one of the two volumes when
the inside test is inclusive (``>= 0``), never in a gap between them.

The light is homogeneous ``(x, y, z, w)``: ``w = 1`` for a point light at ``x, y, z``,
``w = 0`` for a directional light whose light comes *from* direction ``x, y, z``.
"""

from __future__ import annotations

import jax.numpy as jnp


def _lex_less(a, b):
    """bool [...]: a < b in lexicographic order of (x, y, z); a, b [..., 3]."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return (ax < bx) | ((ax == bx) & ((ay < by) | ((ay == by) & (az < bz))))


def edge_plane(a, b, light):
    """Unoriented plane through points a, b [..., 3] and the homogeneous light [4].

    Symmetric in (a, b): the endpoints are first put in lexicographic order.
    Returns (normal [..., 3], d [...]), normal not normalized.
    """
    swap = _lex_less(b, a)[..., None]
    lo = jnp.where(swap, b, a)
    hi = jnp.where(swap, a, b)
    to_light = light[:3] - light[3] * lo
    n = jnp.cross(hi - lo, to_light)
    return n, -jnp.sum(n * lo, axis=-1)


def _normalize_plane(n, d):
    length = jnp.linalg.norm(n, axis=-1)
    safe = jnp.where(length > 0, length, 1)
    return jnp.concatenate([n / safe[..., None], (d / safe)[..., None]], axis=-1), length


def degeneracy_tolerance(dtype) -> float:
    """Relative size below which a triangle counts as degenerate or edge-on: 64 ulps."""
    return 64 * float(jnp.finfo(dtype).eps)


def shadow_volume_planes(tri, light):
    """Edge planes and cap of every triangle's shadow volume.

    Args:
        tri: [T, 3, 3] triangle corners, world units.
        light: [4] homogeneous light position.

    Returns:
        planes: [T, 4, 4]; rows 0-2 edge planes (edge v0v1, v1v2, v2v0), row 3 the cap.
        valid: bool [T]; False for triangles whose shadow volume has no interior at the
            working precision: degenerate (zero-area) triangles and triangles edge-on
            to the light. The test is relative: the third vertex must lie more than
            ``degeneracy_tolerance`` times its distance from the edge off each edge
            plane, and the light (direction) that far off the triangle's plane. Without
            it, a collinear triangle's rounding residues give it a half-space "volume".
    """
    tol = degeneracy_tolerance(tri.dtype)
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    planes = []
    ok = jnp.ones(tri.shape[0], dtype=bool)
    for a, b, c in ((v0, v1, v2), (v1, v2, v0), (v2, v0, v1)):
        n, d = edge_plane(a, b, light)
        side = jnp.sum(n * c, axis=-1) + d
        sign = jnp.where(side < 0, -1, 1).astype(tri.dtype)
        plane, length = _normalize_plane(n * sign[:, None], d * sign)
        reach = jnp.maximum(jnp.linalg.norm(c - a, axis=-1), jnp.linalg.norm(c - b, axis=-1))
        ok &= (length > 0) & (jnp.abs(side) > tol * length * reach)
        planes.append(plane)
    cap_n = jnp.cross(v1 - v0, v2 - v0)
    cap_d = -jnp.sum(cap_n * v0, axis=-1)
    light_side = jnp.sum(cap_n * light[:3], axis=-1) + light[3] * cap_d
    sign = jnp.where(light_side < 0, -1, 1).astype(tri.dtype)
    cap, length = _normalize_plane(cap_n * sign[:, None], cap_d * sign)
    to_light = jnp.linalg.norm(light[:3] - light[3] * v0, axis=-1)
    ok &= (length > 0) & (jnp.abs(light_side) > tol * length * to_light)
    planes.append(cap)
    return jnp.stack(planes, axis=1), ok


def plane_distance(planes, points):
    """Signed distances [..., P] of points [..., 3] to planes [P, 4]."""
    return points @ planes[:, :3].T + planes[:, 3]


def in_shadow_volume(planes, points, cap_bias):
    """bool [...]: points [..., 3] inside one shadow volume given by planes [4, 4].

    Inside means on the inner side of all three edge planes (inclusive) and more than
    ``cap_bias`` (world units) behind the cap.
    """
    dist = plane_distance(planes, points)
    return jnp.all(dist[..., :3] >= 0, axis=-1) & (dist[..., 3] < -cap_bias)


def to_clip_space(planes, view_projection):
    """Transform world planes [..., 4] to clip space given the world->clip matrix [4, 4].

    A plane transforms by the inverse transpose: p_clip = p_world @ inv(VP).
    Clip-space planes are not normalized.
    """
    return planes @ jnp.linalg.inv(view_projection)
