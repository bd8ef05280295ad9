"""Exact software stencil of silhouette shadow volumes: integer counts per view sample.

A GPU rasterizes each silhouette side quad |m| times and each cap once, and the
stencil of a pixel counts the signed crossings of the view ray with those polygons.
In software the same count is a sum of exact sign predicates per (sample, side) and
(sample, cap), evaluated in eye-relative coordinates (the eye is the origin: every
vertex ``X' = X - E``, the light ``L' = l - L_w E``, an evaluation point ``q' = q - E``):

- side of edge AB (A < B): the segment E -> q crosses it iff the line AB pierces the
  triangle (L, E, q), i.e. A and B lie on opposite sides of the plane (E, q, L)
  (``sigma_X = q' . (L' x X')``) and the three edge tests ``pi1 = q' . (A' x B')``,
  ``pi2 = (q' - A') . r`` and ``pi3 = -D`` (``D = L' . (A' x B')``,
  ``r = (L' - L_w A') x (B' - A')``) agree; the ray q -> infinity (ZFAIL) crosses
  it iff AB pierces (q, q + infinity d, L): tests ``pi1``, ``-pi2`` and
  ``rho2 = q' . r``. (``pi2`` equals ``D + q' . r``; that expanded form, with r written
  as ``-(B' x L' + L' x A' + L_w A' x B')``, cancels two products of size |L'| |X'| and
  took the wrong sign in float32 2e-3 world units off a side on ``terrain``, far outside
  any rounding of the inputs: docs/silhouette.md);
- front cap (a triangle T): the line E-q passes through T iff ``pi1`` of T's three
  edges, with the parities (+, +, -) of its sorted edges (lo, mid), (mid, hi),
  (lo, hi), agree; the crossing is beyond q (true cap) or beyond E (cap at infinity,
  eq. 6 of Pečiva 2013) by the sign of ``n_T . lo'`` against ``n_T . q'``;
- back cap (point light only): the ray from L along d = q' passes through T
  (``rho2`` of T's edges with the same parities) on T's far side from the light.

Every value shared by two primitives is computed once per (sample, edge) from one
per-edge table row (vertex terms ``L' x X'`` once per welded vertex), with opaque
products and left-to-right sums (``shadowlab.core.numerics``), and every sign test is
``sgn+`` (``>= 0`` is positive): sides and caps stay watertight, so the counts are
exact integers away from rounding at true shadow boundaries.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..core.numerics import cross3, opaque_multiplier, opaque_zero, ordered_dot

#: columns of an edge table row
EDGE_COLUMNS = 16     # L'xA (3), L'xB (3), A'xB' (3), D (1), A' (3), r (3)


@jax.jit
def vertex_terms(vertices, light):
    """[V, 3]: ``L' x X'`` of every eye-relative vertex ``X'`` [V, 3] (light [4])."""
    mul = opaque_multiplier(opaque_zero(light))
    lv = [light[k] for k in range(3)]
    x = [vertices[:, k] for k in range(3)]
    return jnp.stack(cross3([jnp.broadcast_to(c, x[0].shape) for c in lv], x, mul), axis=1)


@jax.jit
def edge_table(a, b, la, lb, light):
    """Per edge (A < B, eye-relative [E, 3]) the predicate vectors, [E, 16].

    ``la``/``lb`` [E, 3] are rows of :func:`vertex_terms` gathered at A and B (so every
    edge through a vertex sees the same bits). Columns: L'xA', L'xB', A'xB', D, A', r (see
    the module docstring).
    """
    mul = opaque_multiplier(opaque_zero(light))
    lv = [jnp.broadcast_to(light[k], a[:, 0].shape) for k in range(3)]
    lw = light[3]
    av = [a[:, k] for k in range(3)]
    bv = [b[:, k] for k in range(3)]
    # A' x B' as A' x (B' - A'): for a short edge far from the eye the products of
    # A' x B' are |A'| |B'| and cancel to |A'| |B' - A'|, losing the bits that decide
    # which side of the edge a view ray passes (float32, 3 cm edges 40 units away:
    # 7 mm, and a fan of caps around one vertex counted twice); the difference is exact
    # for such edges and the products are no larger than the result
    edge = [bv[k] - av[k] for k in range(3)]
    ab = cross3(av, edge, mul)
    d = ordered_dot(lv, ab, mul)
    r = cross3([lv[k] - mul(lw, av[k]) for k in range(3)], edge, mul)
    cols = [la[:, 0], la[:, 1], la[:, 2], lb[:, 0], lb[:, 1], lb[:, 2], *ab, d, *av, *r]
    return jnp.stack(cols, axis=1)


def _dot(q, row, k, mul):
    return ordered_dot(q, [row[k], row[k + 1], row[k + 2]], mul)


def _side_crossing(qv, row, m, weight, zfail, mul):
    """Stencil and update increments (int32 [...]) of one side per sample.

    qv: the samples' coordinates (3 arrays [...]); row: the side's edge-table row, m its
    multiplicity and weight its update cost, indexable by column (scalars, or arrays
    broadcasting against ``qv``). Shared by the full and the binned pass (same bits).
    """
    sa = _dot(qv, row, 0, mul) >= 0
    sb = _dot(qv, row, 3, mul)
    cross = sa != (sb >= 0)
    p1 = _dot(qv, row, 6, mul) >= 0
    # pi2 relative to A: rounding scales with |q' - A'|, not with |q'| |A'|
    pi2 = ordered_dot([qv[k] - row[10 + k] for k in range(3)],
                      [row[13], row[14], row[15]], mul)
    if zfail:
        t2 = -pi2 >= 0
        t3 = _dot(qv, row, 13, mul) >= 0
    else:
        t2 = pi2 >= 0
        t3 = jnp.broadcast_to(-row[9] >= 0, p1.shape)
    hit = cross & (p1 == t2) & (t2 == t3)
    sgn = jnp.where(sb >= 0, 1, -1).astype(jnp.int32) * (-1 if zfail else 1)
    return jnp.where(hit, m * sgn, 0), jnp.where(hit, weight, 0)


@functools.lru_cache(maxsize=None)
def side_kernel(chunk: int, zfail: bool):
    """Jitted ``run(q, table, m, weight, zero) -> (stencil int32 [S], updates int32 [S])``.

    q [S, 3] eye-relative evaluation points; table [R, 16] edge rows of the silhouette
    records (R % chunk == 0); m int32 [R] multiplicities (0 = no side); weight int32 [R]
    the stencil updates a crossing costs (|m|, or 0 for padding). ZPASS counts crossings
    of the segment E -> q (+m sgn+(sigma_B) each), ZFAIL of the ray q -> infinity
    (-m sgn+(sigma_B) each, the volume is left there). Every sample tests every side
    (the full pass; :func:`binned_side_kernel` tests each sample's screen bin only).
    """
    @jax.jit
    def run(q, table, m, weight, zero):
        mul = opaque_multiplier(zero)
        qv = [q[:, 0], q[:, 1], q[:, 2]]

        def body(i, carry):
            stencil, updates = carry
            blk = jax.lax.dynamic_slice_in_dim(table, i * chunk, chunk)
            mb = jax.lax.dynamic_slice_in_dim(m, i * chunk, chunk)
            wb = jax.lax.dynamic_slice_in_dim(weight, i * chunk, chunk)
            for j in range(chunk):
                ds, du = _side_crossing(qv, blk[j], mb[j], wb[j], zfail, mul)
                stencil, updates = stencil + ds, updates + du
            return stencil, updates

        zeros = jnp.zeros(q.shape[0], jnp.int32)
        return jax.lax.fori_loop(0, table.shape[0] // chunk, body, (zeros, zeros))
    return run


def _binned_loop(q, blocks, start, length, steps, entries, sentinel, crossings, slot):
    """Sum ``crossings(qv, k)`` over per-block lists: (stencil, updates) int32 [S'] per
    sample.

    q [Nb, B, 3]: blocks of B samples; blocks int32 [C, N]: C batches of N of them
    (the padding block repeated: its results are dropped); the samples of a block share
    the list ``entries[start : start + length]`` (start, length int32 [C, N]; entries
    int32 [E] primitive indices), so each step reads one primitive per block (k int32
    [N]) and tests it against the block's B samples. steps int32 [C]: the longest list
    of each batch (the batch loops that often; shorter lists read ``sentinel``, a row
    that must add nothing). A block that appears several times (a split list, one part
    each) gets the sum of its parts. slot int32 [S']: each sample's place in the blocks
    (block * B + lane, the grid's ``slot``; padding entries read any place).
    """
    last = entries.shape[0] - 1

    def batch(args):
        bl, st, ln, n = args
        qb = q[bl]
        qv = [qb[..., 0], qb[..., 1], qb[..., 2]]                        # [N, B] each

        def body(j, carry):
            k = jnp.where(j < ln, entries[jnp.minimum(st + j, last)], sentinel)
            ds, du = crossings(qv, k)
            return carry[0] + ds, carry[1] + du

        zeros = jnp.zeros(qb.shape[:2], jnp.int32)
        return jax.lax.fori_loop(0, n, body, (zeros, zeros))

    lanes = jax.lax.map(batch, (blocks, start, length, steps))
    rows = blocks.reshape(-1)

    def per_sample(x):          # integer sums: the parts' order does not matter
        per_block = jnp.zeros(q.shape[:2], jnp.int32).at[rows].add(
            x.reshape(-1, q.shape[1]), mode="drop")
        return per_block.reshape(-1)[slot]

    return tuple(per_sample(x) for x in lanes)


def _columns(x, k):
    """Rows k [N] of x [R, c] as c columns [c, N, 1] (broadcast over a block's samples)."""
    return x[k].T[..., None]


@functools.lru_cache(maxsize=None)
def binned_side_kernel(zfail: bool):
    """Jitted ``run(q, blocks, start, length, steps, entries, table, m, weight, zero,
    slot)`` -> (stencil, updates) int32 [S'] per sample: :func:`side_kernel` over the
    per-block side lists of :func:`_binned_loop` (the last table row is the sentinel:
    m = weight = 0)."""
    @jax.jit
    def run(q, blocks, start, length, steps, entries, table, m, weight, zero, slot):
        mul = opaque_multiplier(zero)

        def crossings(qv, k):
            return _side_crossing(qv, _columns(table, k), m[k][:, None], weight[k][:, None],
                                  zfail, mul)
        return _binned_loop(q, blocks, start, length, steps, entries, table.shape[0] - 1,
                            crossings, slot)
    return run


SPANS = ("behind", "eye_ray", "front", "none")


def cap_table(edge_rows: np.ndarray, tri_edges: np.ndarray, terms: np.ndarray, span: str,
              back_caps: bool) -> np.ndarray:
    """The columns a caps pass reads, one row per caster: [K, 4 (+ 9) (+ 9)].

    edge_rows [E, 16]: the edge table (:func:`edge_table`); tri_edges int [K, 3]: each
    caster's sorted edges (lo, mid), (mid, hi), (lo, hi) as rows of it; terms [K, 4]:
    n_T and n_T . lo'. Columns: the terms, then (unless ``span == "none"``) A' x B' of
    the three edges (the front cap's tests), then (with ``back_caps``) r of the three
    (the back cap's): 13 or 22 of the 52 columns of three edge rows and the terms, which
    is what the binned loop gathers per step.
    """
    parts = [np.asarray(terms)]
    for used, first in ((span != "none", 6), (back_caps, 13)):
        if used:
            parts.append(edge_rows[:, first:first + 3][tri_edges].reshape(len(tri_edges), 9))
    return np.concatenate(parts, axis=1)


def _cap_crossings(qv, row, s, span, back_caps, mul):
    """Stencil and update increments (int32 [...]) of one caster per sample.

    qv: the samples' coordinates (3 arrays [...]); row: the caster's :func:`cap_table`
    row and s its s_T, indexable by column (scalars, or arrays broadcasting against
    ``qv``). The same operations in the same order for the full and the binned pass (so
    both see the same bits).
    """
    nq = _dot(qv, row, 0, mul)
    sq = jnp.where(nq > 0, 1, -1).astype(jnp.int32)
    back_col = 4
    if span == "none":                                   # back caps only
        stencil = updates = jnp.zeros(jnp.broadcast_shapes(nq.shape, jnp.shape(s)),
                                      jnp.int32)
    else:
        back_col = 13
        f1 = _dot(qv, row, 4, mul) >= 0
        f2 = _dot(qv, row, 7, mul) >= 0
        # the (lo, hi) edge runs against the winding: its bit is the complement of the
        # shared row's (not ``<= 0``), so a ray exactly on an edge (a dot product of
        # exactly 0) is inside exactly one of the two triangles that share it
        f3 = ~(_dot(qv, row, 10, mul) >= 0)
        through = (f1 == f2) & (f2 == f3)
        nlo = row[3]
        same = ((nlo > 0) & (nq > 0)) | ((nlo < 0) & (nq < 0))   # lambda > 0
        rest = nlo - nq                                          # lambda > 1 ...
        far = ((rest > 0) & (nq > 0)) | ((rest < 0) & (nq < 0))
        if span == "behind":
            hit = far
        elif span == "eye_ray":
            hit = same
        else:
            hit = same & ~far & (rest != 0)
        front = through & hit & (s != 0)
        stencil = jnp.where(front, s * sq, 0)
        updates = front.astype(jnp.int32)
    if back_caps:
        b1 = _dot(qv, row, back_col, mul) >= 0
        b2 = _dot(qv, row, back_col + 3, mul) >= 0
        b3 = ~(_dot(qv, row, back_col + 6, mul) >= 0)
        back = (b1 == b2) & (b2 == b3) & (s * sq < 0) & (nq != 0)
        stencil = stencil + back.astype(jnp.int32)
        updates = updates + back.astype(jnp.int32)
    return stencil, updates


def _check_span(span):
    if span not in SPANS:
        raise ValueError(f"span must be one of {SPANS}, got {span!r}")


@functools.lru_cache(maxsize=None)
def cap_kernel(chunk: int, span: str, back_caps: bool):
    """Jitted ``run(q, table, sign, zero) -> (stencil int32 [S], updates int32 [S])``.

    Cap crossings of each sample's view ray, counted as ZFAIL does (+1 where the ray
    leaves a volume, -1 where it enters). q [S, 3] eye-relative points (the ray is
    ``lambda q'``, the point at lambda = 1); table [T, c]: each triangle's
    :func:`cap_table` row for the same ``span`` and ``back_caps`` (its sorted edges
    (lo, mid), (mid, hi), (lo, hi); n_T = (mid - lo) x (hi - lo) and n_T . lo'); sign int32
    [T]: s_T (0 = no volume, also for padding).

    ``span`` selects the front caps counted: "behind" (lambda > 1: true caps behind the
    point), "eye_ray" (lambda > 0: caps at infinity, eq. 6, drawn wherever the eye ray
    meets the triangle), "front" (0 < lambda < 1: caps between the eye and the point,
    which hide it) or "none" (back caps only: a separate pass, so that the true front
    caps can take a depth cut). A front cap crossed adds ``s_T sgn(n_T . q')``; a back cap (point
    light, ``back_caps``) crossed adds +1. Every sample tests every triangle (the full
    pass; :func:`binned_cap_kernel` tests each sample's screen bin only).
    """
    _check_span(span)

    @jax.jit
    def run(q, table, sign, zero):
        mul = opaque_multiplier(zero)
        qv = [q[:, 0], q[:, 1], q[:, 2]]

        def body(i, carry):
            stencil, updates = carry
            tb = jax.lax.dynamic_slice_in_dim(table, i * chunk, chunk)
            sb = jax.lax.dynamic_slice_in_dim(sign, i * chunk, chunk)
            for j in range(chunk):
                ds, du = _cap_crossings(qv, tb[j], sb[j], span, back_caps, mul)
                stencil, updates = stencil + ds, updates + du
            return stencil, updates

        zeros = jnp.zeros(q.shape[0], jnp.int32)
        return jax.lax.fori_loop(0, table.shape[0] // chunk, body, (zeros, zeros))
    return run


@functools.lru_cache(maxsize=None)
def binned_cap_kernel(span: str, back_caps: bool):
    """Jitted ``run(q, blocks, start, length, steps, entries, table, sign, zero, slot)``
    -> (stencil, updates) int32 [S'] per sample: :func:`cap_kernel` over the per-block
    caster lists of :func:`_binned_loop` (the last caster row is the sentinel: sign 0)."""
    _check_span(span)

    @jax.jit
    def run(q, blocks, start, length, steps, entries, table, sign, zero, slot):
        mul = opaque_multiplier(zero)

        def crossings(qv, k):
            return _cap_crossings(qv, _columns(table, k), sign[k][:, None], span,
                                  back_caps, mul)
        return _binned_loop(q, blocks, start, length, steps, entries, table.shape[0] - 1,
                            crossings, slot)
    return run
