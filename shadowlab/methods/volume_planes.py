"""Post-perspective shadow-volume planes and their rounding tolerances.

The node tests of ``clustered_ptsv`` and ``ptsv`` evaluate each triangle's shadow-volume
planes on boxes in post-perspective ``(nx, ny, q = 1 / w)`` space; this module turns the
world planes of ``brute_force.setup`` into those rows, adds the extra culling rows, and
bounds the rounding of every evaluation. The Warp kernel setup
(``shadowlab.kernels.clustered_ptsv``) mirrors it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

_ADJACENT = ((0, 2), (0, 1), (1, 2))     # edge planes meeting at vertex 0, 1, 2
_MARGIN_ULPS = 64


@functools.partial(jax.jit, static_argnames=("extra", "p00", "p11"))
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

    Args:
        planes: [T, 4, 4] world planes (rows: 3 edge planes, cap), working dtype.
        inv_view: [4, 4] view -> world matrix. qmax: max sample q (1 / world units).
        pmax: max |coordinate| of any sample (world units).

    Returns:
        g: [T, 7, 4] rows 0-2 edges, 3 cap, 4-6 extra. tol: [T, 7] tolerances
        (values in units of world distance / w).
    """
    dtype = planes.dtype
    u = jnp.finfo(dtype).eps
    wv = planes @ inv_view
    g = jnp.stack([wv[..., 0] / p00, wv[..., 1] / p11, wv[..., 3], -wv[..., 2]], axis=-1)
    slack = 4 * u * (jnp.sum(jnp.abs(planes[..., :3]), -1) * pmax
                     + jnp.abs(planes[..., 3])) * qmax                      # [T, 4]
    never = jnp.zeros_like(g[:, 0]).at[:, 3].set(1)
    rows, rslack = [], []
    for a, b in _ADJACENT:
        if extra == "culling":
            n = planes[:, a, :3] + planes[:, b, :3]
            ok = jnp.linalg.norm(n, axis=-1) > 1e-3
            row = g[:, a] + g[:, b]
            sl = slack[:, a] + slack[:, b]
        elif extra == "silhouette":
            ea, eb = wv[:, a, 3], wv[:, b, 3]
            ok = ea * eb < 0
            row = jnp.abs(eb)[:, None] * g[:, a] + jnp.abs(ea)[:, None] * g[:, b]
            sl = jnp.abs(eb) * slack[:, a] + jnp.abs(ea) * slack[:, b]
        else:
            ok = jnp.zeros(g.shape[0], bool)
            row, sl = never, jnp.zeros_like(slack[:, 0])
        rows.append(jnp.where(ok[:, None], row, never))
        rslack.append(jnp.where(ok, sl, 0))
    g = jnp.concatenate([g, jnp.stack(rows, axis=1)], axis=1)
    slack = jnp.concatenate([slack, jnp.stack(rslack, axis=1)], axis=1)
    mag = (jnp.abs(g[..., 0]) + jnp.abs(g[..., 1]) + jnp.abs(g[..., 2]) * qmax
           + jnp.abs(g[..., 3]))
    return g, (_MARGIN_ULPS * u * mag + slack).astype(dtype)
