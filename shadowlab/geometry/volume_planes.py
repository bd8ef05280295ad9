"""Post-perspective shadow-volume planes and their rounding tolerances.

The node tests of ``clustered_ptsv`` and ``ptsv`` evaluate each triangle's shadow-volume
planes on boxes in post-perspective ``(nx, ny, q = 1 / w)`` space; this module turns the
world planes of ``geometry.triangle_setup.shadow_volume_planes`` into those rows, adds
the extra culling rows, and bounds the rounding of every evaluation. The Warp kernel setup
(``shadowlab.kernels.clustered_ptsv``) mirrors it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..core.numerics import opaque_multiplier, opaque_zero, ordered_dot, ordered_sum

_ADJACENT = ((0, 2), (0, 1), (1, 2))     # edge planes meeting at vertex 0, 1, 2
_MARGIN_ULPS = 64


def post_perspective_planes(planes, inv_view, qmax, pmax, *, extra: str, p00: float,
                            p11: float):
    """Planes in (nx, ny, q, 1) space and their rounding tolerances.

    A world plane W (row vector) becomes the view-space plane W' = W inv(V); for a
    point with view coordinates (x, y, -w), NDC nx = p00 x / w, ny = p11 y / w and
    q = 1 / w:  W . p / w = (W'0 / p00) nx + (W'1 / p11) ny + W'3 q - W'2.  The sign
    is that of the world test (w > 0), and the form is affine in (nx, ny, q), so box
    corners give exact extremes.

    Extra rows (``extra``):
      - "culling" (2014): per vertex, the sum of its two adjacent edge-plane
        equations: the plane through the vertex and the light whose normal is the half
        vector of the two (unit) normals. Any point inside both planes is inside it,
        so it never rejects a shadowed point. Skipped (a never-rejecting row) when the
        normals nearly cancel (|n_a + n_b| < 1e-3: degenerate or edge-on wedges).
      - "silhouette" (2011 PTSV's 2D silhouette edges): per vertex whose two edge
        planes see the eye on opposite sides, the non-negative combination
        |E_b(eye)| E_a + |E_a(eye)| E_b, the plane through the eye and the light-vertex
        line: a 2D line on screen bounding the volume's projection.
      - "none".

    Rounding: every value is the same IEEE operations in the same order for any T
    (the Warp setup kernel repeats them): products opaque (``core.numerics``: never fused
    into FMAs), sums left to right (``W inv(V)`` as
    ``((p0 m0j + p1 m1j) + p2 m2j) + p3 m3j``, no dot), ``1 / p00`` and ``1 / p11``
    rounded once on the host and multiplied, slack ``(s3 pmax + |d|) (qmax 4u)`` with
    ``s3 = (|n0| + |n1|) + |n2|``, ``tol = mag 64u + slack`` with
    ``mag = ((|g0| + |g1|) + |g2| qmax) + |g3|`` (4u and 64u are powers of two).

    Args:
        planes: [T, 4, 4] world planes (rows: 3 edge planes, cap), working dtype, or
            the same as [T, 16] (reshaped inside the compiled program: an eager reshape
            copies, 12 ms at 500k casters).
        inv_view: [4, 4] view -> world matrix. qmax: max sample q (1 / world units).
        pmax: max |coordinate| of any sample (world units).

    Returns:
        g: [T, 7, 4] rows 0-2 edges, 3 cap, 4-6 extra. tol: [T, 7] tolerances
        (values in units of world distance / w).
    """
    # the reciprocals rounded once, on the host; passed as data, so that one compiled
    # program serves every camera
    recip = jnp.asarray(np.array([1.0 / p00, 1.0 / p11]).astype(planes.dtype))
    return _post_perspective_planes(planes, inv_view, qmax, pmax, recip, extra=extra)


@functools.partial(jax.jit, static_argnames=("extra",))
def _post_perspective_planes(planes, inv_view, qmax, pmax, recip, *, extra: str):
    """:func:`post_perspective_planes` with recip = (1 / p00, 1 / p11) [2] rounded to
    the working dtype."""
    dtype = planes.dtype
    u = float(jnp.finfo(dtype).eps)
    mul = opaque_multiplier(opaque_zero(inv_view))

    t = planes.shape[0]
    planes = planes.reshape(t, 4, 4)
    p = [[planes[:, i, k] for k in range(4)] for i in range(4)]     # p[plane][coef]: [T]
    m = [[inv_view[i, j] for j in range(4)] for i in range(4)]
    r00, r11 = recip[0], recip[1]
    q4 = mul(qmax, jnp.asarray(4 * u, dtype))
    wv, g, inner, slack = [], [], [], []
    for i in range(4):
        w = [ordered_dot(p[i], [m[k][j] for k in range(4)], mul) for j in range(4)]
        wv.append(w)
        g.append([mul(w[0], r00), mul(w[1], r11), w[3], -w[2]])
        s3 = ordered_sum(jnp.abs(p[i][k]) for k in range(3))
        inner.append(mul(s3, pmax) + jnp.abs(p[i][3]))
        slack.append(mul(inner[i], q4))
    one, nil = jnp.ones(t, dtype), jnp.zeros(t, dtype)
    for a, b in _ADJACENT:
        if extra == "culling":
            n = [p[a][k] + p[b][k] for k in range(3)]
            ok = jnp.sqrt(ordered_dot(n, n, mul)) > 1e-3
            row = [g[a][k] + g[b][k] for k in range(4)]
            sl = slack[a] + slack[b]
        elif extra == "silhouette":
            ea, eb = wv[a][3], wv[b][3]
            ok = mul(ea, eb) < 0
            row = [mul(jnp.abs(eb), g[a][k]) + mul(jnp.abs(ea), g[b][k]) for k in range(4)]
            sl = mul(jnp.abs(eb), slack[a]) + mul(jnp.abs(ea), slack[b])
        else:
            ok, row, sl = jnp.zeros(t, bool), [nil, nil, nil, one], nil
        g.append([jnp.where(ok, x, y) for x, y in zip(row, [nil, nil, nil, one])])
        slack.append(jnp.where(ok, sl, 0))
    c64 = jnp.asarray(_MARGIN_ULPS * u, dtype)
    tol = []
    for r in range(7):
        mag = ordered_sum([jnp.abs(g[r][0]), jnp.abs(g[r][1]), mul(jnp.abs(g[r][2]), qmax),
                           jnp.abs(g[r][3])])
        tol.append(mul(mag, c64) + slack[r])
    g = jnp.stack([jnp.stack(row, axis=-1) for row in g], axis=1)
    return g, jnp.stack(tol, axis=1).astype(dtype)
