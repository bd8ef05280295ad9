"""The canonical triangle setup: shadow-volume planes of triangles from a light.

A triangle's shadow volume from a light is bounded by three *edge planes* (each
through one edge and the light) and its *cap* (the triangle's own plane). Planes are
``(nx, ny, nz, d)`` with unit normals, so ``dot(n, p) + d`` is a signed distance in
world units. Orientation: edge planes are non-negative on the triangle's side; the
cap is positive on the light's side.

Edge planes are computed from the edge's endpoints in lexicographic order of their
coordinates (:func:`lex_less`), so two triangles sharing an edge evaluate bit-identical
expressions and get exactly negated (or equal) planes (polygon soup: vertices are
compared by value, not index). A point exactly on a shared edge plane is then inside
one of the two volumes when the inside test is inclusive (``>= 0``), never in a gap.

The light is homogeneous ``(x, y, z, w)``: ``w = 1`` for a point light at ``x, y, z``,
``w = 0`` for a directional light whose light comes *from* direction ``x, y, z``.

Every exact hard-shadow method runs :func:`shadow_volume_planes`; the Warp setup kernel
(``shadowlab.kernels.clustered_ptsv``) repeats its operations in the same order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..core.numerics import cross3, opaque_multiplier, opaque_zero, ordered_dot


def degeneracy_tolerance(dtype) -> float:
    """Relative size below which a triangle counts as degenerate or edge-on: 64 ulps."""
    return 64 * float(jnp.finfo(dtype).eps)


def lex_less(a, b):
    """bool [T]: a < b in lexicographic order of (x, y, z); a, b: 3 columns [T]."""
    ax, ay, az = a
    bx, by, bz = b
    return (ax < bx) | ((ax == bx) & ((ay < by) | ((ay == by) & (az < bz))))


def _plane(n, d, flip, mul):
    """Oriented, normalised plane [4 columns of T] and the normal's length [T]."""
    n = [jnp.where(flip, -x, x) for x in n]
    d = jnp.where(flip, -d, d)
    length = jnp.sqrt(ordered_dot(n, n, mul))
    safe = jnp.where(length > 0, length, 1)
    return [n[0] / safe, n[1] / safe, n[2] / safe, d / safe], length


@jax.jit
def shadow_volume_planes(tri, light):
    """Edge planes and cap of every triangle's shadow volume.

    Every value is the same IEEE operations in the same order for any T (the numerics
    policy of ``shadowlab.core.numerics``): opaque products (never fused into FMAs), sums
    of three as ``(x0 + x1) + x2`` (no reductions), each normal component and the offset
    divided by the length (four true divisions, no reciprocal), lengths
    ``sqrt((n0 n0 + n1 n1) + n2 n2)``, sides flipped by negation.

    Args:
        tri: [T, 3, 3] triangle corners (world units), float32 or float64.
        light: [4] homogeneous light, same dtype.

    Returns:
        planes: [T, 16], four planes of four coefficients ``(nx, ny, nz, d)``: edge
            planes of edges v0v1, v1v2, v2v0, then the cap (reshape to [T, 4, 4]).
        valid: bool [T]; False for triangles whose shadow volume has no interior at the
            working precision: degenerate (zero-area) triangles and triangles edge-on
            to the light. The test is relative: the third vertex must lie more than
            :func:`degeneracy_tolerance` times its distance from the edge off each edge
            plane, and the light (direction) that far off the triangle's plane. Without
            it, a collinear triangle's rounding residues give it a half-space "volume".
    """
    mul = opaque_multiplier(opaque_zero(light))
    tol = degeneracy_tolerance(tri.dtype)
    v = [[tri[:, i, k] for k in range(3)] for i in range(3)]
    lxyz, lw = [light[k] for k in range(3)], light[3]

    def norm(x):
        return jnp.sqrt(ordered_dot(x, x, mul))

    def sub(a, b):
        return [a[k] - b[k] for k in range(3)]

    cols, ok = [], jnp.ones(tri.shape[0], dtype=bool)
    for i in range(3):
        a, b, c = v[i], v[(i + 1) % 3], v[(i + 2) % 3]
        swap = lex_less(b, a)
        lo = [jnp.where(swap, b[k], a[k]) for k in range(3)]
        hi = [jnp.where(swap, a[k], b[k]) for k in range(3)]
        to_light = [lxyz[k] - mul(lw, lo[k]) for k in range(3)]
        n = cross3(sub(hi, lo), to_light, mul)
        d = -ordered_dot(n, lo, mul)
        # n . (c - lo), not n . c + d: the sum cancels terms of size |n| |lo|, whose
        # rounding can exceed the degeneracy threshold (relative to the triangle's
        # size) when the triangle is small against its distance from the frame origin.
        side = ordered_dot(n, sub(c, lo), mul)
        plane, length = _plane(n, d, side < 0, mul)
        reach = jnp.maximum(norm(sub(c, a)), norm(sub(c, b)))
        ok &= (length > 0) & (jnp.abs(side) > mul(mul(tol, length), reach))
        cols += plane
    cn = cross3(sub(v[1], v[0]), sub(v[2], v[0]), mul)
    cd = -ordered_dot(cn, v[0], mul)
    light_dir = [lxyz[k] - mul(lw, v[0][k]) for k in range(3)]
    light_side = ordered_dot(cn, light_dir, mul)    # not cn . L + L.w cd, for the same reason
    plane, length = _plane(cn, cd, light_side < 0, mul)
    ok &= (length > 0) & (jnp.abs(light_side) > mul(mul(tol, length), norm(light_dir)))
    cols += plane
    return jnp.stack(cols, axis=1), ok
