"""Light-space rasterizer: triangles over the R x R texel grid of a light-camera face.

A building block shared by the shadow map and the irregular z-buffer (IZB). Three
coverage modes decide whether triangle T produces a fragment in texel t:

- ``"standard"``: the texel centre is inside T (a shadow map), with a top-left rule
  on exact zeros so a centre on an edge shared by two triangles is covered once;
- ``"inner"``: the closed texel square lies inside T (a conservative shadow map), with
  two tests, ``inner_test="corners"`` (all four corners inside: Tokuyoshi and Mizokuchi
  2018, Program 1) and ``"circle"`` (the texel's circumscribed circle inside: Hertel et
  al. 2009); ``circle`` implies ``corners``;
- ``"outer"``: the closed texel square meets T (frustum tracing in the IZB).

**Homogeneous edge functions** (Olano and Greer 1997). A face maps a world point X to
homogeneous texel coordinates h = M (X, 1) = (u w, v w, w) (:func:`homogeneous_matrix`;
w = 1 on an orthographic face, w = depth along the view axis on a perspective one). With
P_i = h(vertex i), the edge functions E_i(u, v) = (P_j x P_k) . (u, v, 1) ((i, j, k)
cyclic) and D = det[P_0, P_1, P_2] give barycentrics b_i = E_i / D of (u, v, 1) =
sum_i b_i P_i, so (u, v) is covered iff every b_i >= 0, iff the ray from the light through
(u, v) meets T in front of the light. That holds for triangles reaching behind a point
light too: no clipping is needed, and a triangle entirely behind the light covers nothing.
Edge rows are stored as ``A_i = sign(D) (P_j x P_k)``, so A_i . (u, v, 1) >= 0 inside.

**Depth** ``delta`` increases away from the light and is affine in (u, v) over a plane:
orthographic faces use the depth along the view axis (world units); perspective faces
``delta = -near / depth`` (dimensionless, in [-1, 0) beyond ``near``; ``1/depth`` is affine
over a plane). Its plane over T is ``Z . (u, v, 1)`` with Z = sum_i kappa_i A_i / |D|,
kappa_i = delta_i w_i. The extremes of an affine function over a texel square are at its
corners, which is how conservative depths are bounded.

**Fragments over a set of texels.** Work is enumerated only over a sorted set of texel
keys ``face * R * R + row * R + column`` (all texels for a dense raster, or the texels
holding view samples for the shadow map and IZB): per triangle, its texel bounding box
row by row, and the keys of each row inside the box, or for a wide box inside the
columns of the row that can pass the coverage test (:func:`row_spans`), found by rank
(:class:`KeyRank`). Counts are exact before any array is allocated; nothing is
truncated.

Distances to edges are measured in texels. A margin ``tau`` (texels) makes the inner
test stricter and the outer test looser; ``rounding_margin`` sizes it from the data.
Everything here is float64 NumPy set-up plus elementwise evaluation that runs in NumPy or
under ``jax.jit`` (``xp``) in the dtype of its inputs. The methods rasterize with
:func:`raster`: the exact count (:func:`row_segments`: NumPy bookkeeping with jitted
per-row passes for the spans and the key ranks), then one jit-compiled
fill at static capacities (float64, :func:`x64`) that writes only the fragment arrays its
caller reads.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket, check_int32, pad, run_offsets

from ..core.numerics import cross_columns, ordered_dot
from ..scene.light_camera import LightCamera, LightFace, affine_rows, columns

MODES = ("standard", "inner", "outer")
INNER_TESTS = ("corners", "circle")
#: corner offsets of a texel relative to its lower corner (column, row)
CORNERS = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0))
HALF_DIAGONAL = math.sqrt(0.5)
EPS64 = float(np.finfo(np.float64).eps)


def homogeneous_matrix(face: LightFace) -> np.ndarray:
    """float64 [3, 4]: world (x, y, z, 1) -> (u w, v w, w) of ``face`` (texel units).

    ``u = h0 / h2``, ``v = h1 / h2`` equal ``face.project``'s texel coordinates (column,
    row); ``w = h2`` is 1 (orthographic) or the depth along the view axis (perspective).
    """
    vp = face.view_projection
    r = float(face.resolution[0])
    return np.stack([0.5 * r * (vp[0] + vp[3]), 0.5 * r * (vp[3] - vp[1]), vp[3]])


def face_depth(face: LightFace, depth: np.ndarray) -> np.ndarray:
    """float64 [...]: ``delta`` of points at view-axis ``depth`` [...] (world units).

    On a perspective face a point on the light's plane (depth 0) has an infinite delta;
    the callers treat it (a receiver cut that reaches the light), so no warning is
    raised for it."""
    depth = np.asarray(depth, dtype=np.float64)
    if face.orthographic:
        return depth
    with np.errstate(divide="ignore"):
        return -face.near / depth


@dataclasses.dataclass(frozen=True, eq=False)
class FaceSetup:
    """Per-triangle raster set-up on one face (all float64 NumPy).

    Attributes:
        edges: [T, 3, 3] rows ``A_i`` (a, b, c): ``A_i . (u, v, 1) >= 0`` inside edge i.
        norms: [T, 3] ``|(a, b)|`` of each edge row (0 for an edge whose line is at
            infinity, then the row is a constant sign).
        depth: [T, 3] depth plane Z: ``delta_T(u, v) = Z . (u, v, 1)``.
        bbox: int64 [T, 4] inclusive texel box (col0, col1, row0, row1), clamped to the
            grid; empty (col0 > col1) for triangles covering nothing.
        front: bool [T] all three vertices in front of the light (w > 0).
        ok: bool [T] rasterizable (D != 0 and not entirely behind the light).
        vertex_delta: [T, 3] delta of the vertices (meaningful where ``front``).
        vertex_w: [T, 3] homogeneous w of the vertices; absdet: [T] |D|.
        unit: [T, 3, 3] edge rows divided by their norms: ``unit_i . (u, v, 1)`` is the
            signed distance to edge i in texels (+-inf constants for an edge at infinity).
    """

    edges: np.ndarray
    norms: np.ndarray
    depth: np.ndarray
    bbox: np.ndarray
    front: np.ndarray
    ok: np.ndarray
    vertex_delta: np.ndarray
    vertex_w: np.ndarray
    absdet: np.ndarray
    unit: np.ndarray


def setup_face(face: LightFace, triangles: np.ndarray, pad: float = 1.0) -> FaceSetup:
    """Raster set-up of world ``triangles`` [T, 3, 3] on ``face`` (float64).

    Computed column by column (each of the T triangles' 3 x 3 values as its own [T]
    array): NumPy's cross products, row-wise dot products and reductions across the
    short axes of [T, 3, 3] arrays cost about 0.8 s at 1M triangles, the column form a
    fraction of that. Every sum of three products is ``(p0 + p1) + p2`` (the homogeneous
    corners: ``((x m0 + y m1) + z m2) + m3``, each product rounded once); the rounding
    is covered by the raster's margins (:func:`rounding_margin`), as before when BLAS
    and ``einsum`` picked the order.

    Args:
        pad: texels added around each bounding box: the standard (centre) and inner
            tests need none, the outer test at least its margin tau (the shadow map
            passes 0, the IZB 2 tau; the default of one texel covers margins up to 1).
    """
    tri = np.asarray(triangles, dtype=np.float64)
    n = len(tri)
    r = int(face.resolution[0])
    m = homogeneous_matrix(face)
    corners = [columns(tri[:, i]) for i in range(3)]               # [3, T] each
    h = [affine_rows(c, m, range(3)) for c in corners]             # h[i] = (u w, v w, w)
    if face.orthographic:
        ones = np.ones(n)
        h = [[hi[0], hi[1], ones] for hi in h]
        f = face.forward
        shift = float(f @ face.eye)
        vdelta = [affine_rows(c, np.array([[f[0], f[1], f[2], 0.0]]), (0,))[0] - shift
                  for c in corners]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            vdelta = [-face.near / hi[2] for hi in h]
    w = [hi[2] for hi in h]
    rows = [cross_columns(h[(i + 1) % 3], h[(i + 2) % 3]) for i in range(3)]
    det = ordered_dot(h[0], rows[0], np.multiply)
    sign = np.where(det < 0, -1.0, 1.0)
    # every [T, k] output is the transposed view of a [k, T] buffer written row by row
    # (a strided [T, k] write or stack costs several times more)
    edge = np.empty((3, 3, n))                                      # edge[i][k]: [T]
    unit = np.empty((3, 3, n))
    for i in range(3):
        for k in range(3):
            np.multiply(rows[i][k], sign, out=edge[i, k])
    absdet = np.abs(det)
    front = (w[0] > 0) & (w[1] > 0) & (w[2] > 0)
    ok = (absdet > 0) & ((w[0] > 0) | (w[1] > 0) | (w[2] > 0))
    safe = np.where(absdet > 0, absdet, 1.0)
    kappa = ([vdelta[i] * w[i] for i in range(3)] if face.orthographic
             else [-face.near] * 3)
    depth = np.empty((3, n))
    for k in range(3):
        np.divide(ordered_dot(kappa, edge[:, k], np.multiply), safe, out=depth[k])
    norm = np.empty((3, n))
    for i in range(3):
        np.hypot(edge[i, 0], edge[i, 1], out=norm[i])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # meaningful where front; the boxes below read them only there
        u = [h[i][0] / w[i] for i in range(3)]
        v = [h[i][1] / w[i] for i in range(3)]
    with np.errstate(invalid="ignore"):
        lo_u = np.floor(np.minimum(np.minimum(u[0], u[1]), u[2]) - pad)
        hi_u = np.floor(np.maximum(np.maximum(u[0], u[1]), u[2]) + pad)
        lo_v = np.floor(np.minimum(np.minimum(v[0], v[1]), v[2]) - pad)
        hi_v = np.floor(np.maximum(np.maximum(v[0], v[1]), v[2]) + pad)
    fr = front & ok
    # the box of a front triangle clamped to the grid, the whole grid for the others
    box = np.empty((4, n), dtype=np.int64)
    for k, (value, low, other) in enumerate(((lo_u, 0, 0), (hi_u, -1, r - 1),
                                             (lo_v, 0, 0), (hi_v, -1, r - 1))):
        box[k] = np.clip(np.where(fr, value, other), low, r - 1)
    bbox = box.T
    off = fr & ((hi_u < 0) | (lo_u > r - 1) | (hi_v < 0) | (lo_v > r - 1))
    _set_boxes(box, off, (1, 0, 1, 0))
    for i in range(3):
        flat = np.flatnonzero(norm[i] == 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                np.divide(edge[i][k], norm[i], out=unit[i, k])
        unit[i, :2, flat] = 0.0
        unit[i, 2, flat] = np.where(edge[i][2][flat] >= 0, np.inf, -np.inf)
    edges = edge.transpose(2, 0, 1)
    norms = norm.T
    for t in np.flatnonzero(ok & ~front):   # reaching behind the light: clip the grid
        bbox[t] = _clipped_box(edges[t], norms[t], r, pad)
    _set_boxes(box, ~ok, (1, 0, 1, 0))
    return FaceSetup(edges, norms, depth.T, bbox, front, ok, np.array(vdelta).T,
                     np.array(w).T, absdet, unit.transpose(2, 0, 1))


def _set_boxes(box: np.ndarray, where: np.ndarray, value: tuple[int, ...]) -> None:
    """Set the columns ``where`` (bool [T]) of ``box`` [4, T] to ``value``."""
    t = np.flatnonzero(where)
    if len(t):
        box[:, t] = np.asarray(value, dtype=box.dtype)[:, None]


def _clipped_box(edges: np.ndarray, norms: np.ndarray, r: int, pad: float) -> np.ndarray:
    """Texel box of the grid square clipped by the three half-planes (each moved out by
    ``pad`` texels), for triangles whose projection is unbounded."""
    poly = [(0.0, 0.0), (r, 0.0), (r, r), (0.0, r)]
    for (a, b, c), n in zip(edges, norms):
        c = c + pad * n
        out = []
        for k, p in enumerate(poly):
            q = poly[(k + 1) % len(poly)]
            fp, fq = a * p[0] + b * p[1] + c, a * q[0] + b * q[1] + c
            if fp >= 0:
                out.append(p)
            if (fp >= 0) != (fq >= 0):
                s = fp / (fp - fq)
                out.append((p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])))
        poly = out
        if not poly:
            return np.array([1, 0, 1, 0])
    pts = np.array(poly)
    lo = np.clip(np.floor(pts.min(axis=0)), 0, r - 1)
    hi = np.clip(np.floor(pts.max(axis=0)), 0, r - 1)
    return np.array([lo[0], hi[0], lo[1], hi[1]], dtype=np.int64)


def texel_keys(face: np.ndarray, uv: np.ndarray, resolution: int) -> np.ndarray:
    """int64 [N]: the texel key of points on ``face`` [N] at texel coordinates ``uv``
    [N, 2] (the one texel function: floor, clamped to the grid)."""
    r = int(resolution)
    ij = np.clip(np.floor(uv), 0, r - 1).astype(np.int64)
    return (np.asarray(face, dtype=np.int64) * r + ij[:, 1]) * r + ij[:, 0]


def row_segments(setups: list[FaceSetup], keys: np.ndarray, resolution: int,
                 select: list[np.ndarray] | None = None, mode: str | None = None,
                 inner_test: str = "corners", tau: float = 0.0, eps: float = EPS64):
    """The counting pass of the rasterizer: per (triangle, row of its box) on each face,
    the run of ``keys`` inside the row's columns (found by :class:`KeyRank`): the box's
    columns, or with a ``mode`` for
    a box at least :func:`narrow_min_columns` wide only those that can pass the mode's
    coverage test (:func:`row_spans`).

    Args: as :func:`candidates`.
    Returns:
        face int64 [M], tri int64 [M], first int64 [M] (index into ``keys``), count
        int64 [M]; the fragments are, in order, ``first[m] + arange(count[m])`` of each
        segment m (sorted by face, triangle, row), ``count.sum()`` of them.
    """
    r = int(resolution)
    out = []
    rank = key_rank(keys, len(setups) * r * r)
    face_ends = np.searchsorted(keys, np.arange(len(setups) + 1) * r * r)
    for f, st in enumerate(setups):
        min_columns = narrow_min_columns(int(face_ends[f + 1] - face_ends[f]), r * r)
        b = st.bbox
        use = (b[:, 0] <= b[:, 1]) & (b[:, 2] <= b[:, 3])
        if select is not None:
            use &= select[f]
        t = np.flatnonzero(use)
        nrows = b[t, 3] - b[t, 2] + 1
        rt = np.repeat(t, nrows)
        row = b[rt, 2] + run_offsets(nrows)
        col0, col1 = b[rt, 0], b[rt, 1]
        if mode is not None:
            wide = b[t, 1] - b[t, 0] + 1 >= min_columns
            if wide.any():
                rows_of_wide = np.repeat(wide, nrows)
                tw = t[wide]
                col0[rows_of_wide], col1[rows_of_wide] = row_spans(
                    st.unit[tw], b[tw], np.repeat(np.arange(len(tw)), nrows[wide]),
                    row[rows_of_wide], mode, inner_test, tau, eps)
        base = (f * r + row) * r
        if rank is None:
            lo = np.searchsorted(keys, base + col0, side="left")
            hi = np.searchsorted(keys, base + col1, side="right")
        else:           # the same indices: the number of keys below each end
            lo, hi = rank(base + col0, base + col1 + 1)
        keep = hi > lo
        out.append((np.full(int(keep.sum()), f), rt[keep], lo[keep], (hi - lo)[keep]))
    # one face (no concatenation), and no copy of arrays that are int64 already
    return tuple((out[0][i] if len(out) == 1 else np.concatenate([o[i] for o in out]))
                 .astype(np.int64, copy=False) for i in range(4))


class KeyRank:
    """The number of sorted unique texel ``keys`` [K] (in [0, size)) below any texel key,
    from a bitmap of the keys (one bit per texel) and the count of keys before each
    64-bit word: ``rank(x) = before[x >> 6] + popcount(word[x >> 6] & (2^(x & 63) - 1))``.
    The same indices as ``np.searchsorted(keys, x)``, in a few elementwise passes
    instead of a binary search per lookup (the two searches of each of the 7.4 M rows of
    1M casters on an 8192 x 8192 map: 2 x 270 ms; ranks 2 x 135 ms); 0.25 bytes per
    texel, held on the host and as device arrays."""

    def __init__(self, keys: np.ndarray, size: int):
        keys = np.asarray(keys, np.int64)
        n_words = size // 64 + 1                    # lookups go up to x = size
        word_of = keys >> 6
        bits = np.left_shift(np.uint64(1), (keys & 63).astype(np.uint64))
        self.words = np.zeros(n_words, np.uint64)
        if len(keys):
            first = np.flatnonzero(np.diff(word_of, prepend=-1))
            self.words[word_of[first]] = np.bitwise_or.reduceat(bits, first)
        self.before = np.zeros(n_words, np.int64)
        np.cumsum(np.bincount(word_of, minlength=n_words)[:-1], out=self.before[1:])
        with x64():
            self._device = (jnp.asarray(self.words), jnp.asarray(self.before))

    def __call__(self, *xs: np.ndarray) -> tuple[np.ndarray, ...] | np.ndarray:
        """int64 [N] per argument: the number of keys < x, for int64 x [N] in [0, size]
        (one jitted pass, int64 under :func:`x64`)."""
        n = len(xs[0])
        cap = bucket(n, minimum=1024)
        with x64():
            out = _rank(*self._device, tuple(jnp.asarray(pad(x, cap, dtype=np.int64))
                                             for x in xs))
            out = tuple(np.asarray(r)[:n] for r in out)
        return out if len(xs) > 1 else out[0]


@jax.jit
def _rank(words, before, xs):
    def one(x):
        w = x >> 6
        below = jnp.left_shift(jnp.uint64(1), (x & 63).astype(jnp.uint64)) - jnp.uint64(1)
        return (before.at[w].get(mode="promise_in_bounds")
                + jax.lax.population_count(words.at[w].get(mode="promise_in_bounds")
                                           & below).astype(jnp.int64))
    return tuple(one(x) for x in xs)


def key_rank(keys: np.ndarray, size: int) -> KeyRank | None:
    """The row-run lookup of :func:`row_segments`: a :class:`KeyRank` of the sorted unique
    ``keys`` in [0, size). (None selects binary searches, the former lookup, which the
    tests and ``docs/repro/raster_spans_ab.py`` compare with.)"""
    return KeyRank(keys, size)


#: boxes at least this wide are always narrowed to their rows' spans (docs/shadow_map.md,
#: "Row spans")
NARROW_MIN_COLUMNS = 16
#: narrower boxes, down to NARROW_DENSE_COLUMNS, are narrowed where a box row is expected
#: to hold at least NARROW_MIN_KEYS keys (its width times the face's key density): over
#: sparse keys a span drops few candidates and costs a row pass
NARROW_DENSE_COLUMNS = 8
NARROW_MIN_KEYS = 2


def narrow_min_columns(face_keys: int, face_texels: int) -> int:
    """The narrowest box whose rows :func:`row_segments` narrows to their spans, on a face
    whose ``face_keys`` keys fill its ``face_texels`` texels: the width at which a row is
    expected to hold ``NARROW_MIN_KEYS`` keys, at least NARROW_DENSE_COLUMNS, and never
    above NARROW_MIN_COLUMNS (which wins if set below the other)."""
    if face_keys <= 0:
        return NARROW_MIN_COLUMNS
    want = -(-int(NARROW_MIN_KEYS) * face_texels // face_keys)     # exact integer ceil
    return int(min(NARROW_MIN_COLUMNS, max(NARROW_DENSE_COLUMNS, want)))


#: fragment capacities per octave (:func:`core.capacity.bucket`): with 2 a capacity is at
#: most 1.5x the candidates (a power of two: up to 2x), and the fill and the IZB's tracing
#: process the padding too, so fewer candidates mean less work; twice the compiled sizes
FRAGMENT_BUCKET_STEPS = 2


def row_spans(unit: np.ndarray, box: np.ndarray, owner: np.ndarray, row: np.ndarray,
              mode: str, inner_test: str = "corners", tau: float = 0.0, eps: float = EPS64
              ) -> tuple[np.ndarray, np.ndarray]:
    """The columns of each row of a triangle's box that can pass ``mode``'s coverage test.

    At a fixed row every edge's test (:func:`coverage_terms`) is affine in the column,
    ``a col + K(row) >= 0``, so the passing columns of a row form one interval: a lower
    bound from each edge with a > 0, an upper one from each edge with a < 0 (an edge
    with a = 0 bounds no column). Each bound, ``alpha + beta row`` per triangle and edge,
    is widened by the rounding of both this evaluation and the coverage test's
    (relative ``eps``, the evaluation dtype's, times the magnitude of the terms over the
    box, in columns) and then by one more column, so the interval holds every column
    the test can accept and the test still decides each fragment. Thin triangles across
    many rows (fur strands) cover few of their box's texels: the raster then fills and
    tests only those.

    Args:
        unit: float64 [T, 3, 3] the triangles' unit edge rows (``FaceSetup.unit``);
        box: int64 [T, 4] their texel boxes (col0, col1, row0, row1);
        owner: int [M] the triangle of each row; row: int [M] rows inside its box;
        tau: scalar margin (texels); eps: the coverage test's relative rounding.
    Returns:
        (lo, hi) int64 [M] within [col0 - 1, col1 + 1] of the row's box; lo > hi for a
        row with no passing column.
    """
    s, sign_tau, const = coverage_terms(mode, inner_test)
    thr = const + sign_tau * float(tau)
    col0, col1 = box[:, 0].astype(np.float64), box[:, 1].astype(np.float64)
    width = max(abs(float(tau)), 1.0) + HALF_DIAGONAL
    v_max = box[:, 3].astype(np.float64) + 1.5
    lo_t, hi_t = [], []             # per edge: (alpha, beta) [T] of the bound on columns
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for i in range(3):
            a, b, c = unit[:, i, 0], unit[:, i, 1], unit[:, i, 2]
            half = 0.5 * (np.abs(a) + np.abs(b))
            safe = np.where(a != 0, a, 1.0)
            # the test at column col, row y: a col + k0 + b y >= 0
            k0 = (0.5 * a + 0.5 * b + c) + (s * half - thr)
            alpha, beta = -k0 / safe, -b / safe
            # magnitude of every term either evaluation sums, over the box
            size = (np.abs(a) * (np.abs(col1) + 2.0) + np.abs(b) * v_max + np.abs(c) + half
                    + width)
            slack = 16.0 * eps * size / np.abs(safe) + 1.0
            ok = np.isfinite(alpha) & np.isfinite(beta) & np.isfinite(slack)
            lo_t.append((np.where(ok & (a > 0), alpha - slack, -np.inf),
                         np.where(ok & (a > 0), beta, 0.0)))
            hi_t.append((np.where(ok & (a < 0), alpha + slack, np.inf),
                         np.where(ok & (a < 0), beta, 0.0)))
    # per row: one fused pass (gathers of the per-triangle terms, products, rounding,
    # clamps) instead of some forty NumPy passes over the rows
    t_cap, m_cap = bucket(len(col0), minimum=16), bucket(len(row), minimum=1024)
    terms = [col0, col1] + [x for pair in lo_t + hi_t for x in pair]
    with x64():
        lo, hi = _span_rows(tuple(jnp.asarray(pad(x, t_cap)) for x in terms),
                            jnp.asarray(pad(owner, m_cap, dtype=np.int64)),
                            jnp.asarray(pad(row, m_cap, dtype=np.float64)))
        return np.asarray(lo)[: len(row)], np.asarray(hi)[: len(row)]


@jax.jit
def _span_rows(terms, owner, y):
    """(lo, hi) int64 [M] of :func:`row_spans` from the per-triangle terms (float64 [T]:
    col0, col1, then alpha and beta of each edge's lower bound, then of its upper
    bound), each row's triangle ``owner`` [M] and row ``y`` [M] (float64)."""
    def g(x):
        return x.at[owner].get(mode="promise_in_bounds")

    col0, col1 = g(terms[0]), g(terms[1])
    lo, hi = col0, col1
    for i in range(3):
        lo = jnp.maximum(lo, jnp.ceil(g(terms[2 + 2 * i]) + g(terms[3 + 2 * i]) * y))
        hi = jnp.minimum(hi, jnp.floor(g(terms[8 + 2 * i]) + g(terms[9 + 2 * i]) * y))
    lo = jnp.minimum(lo, col1 + 1)
    hi = jnp.maximum(hi, col0 - 1)
    return lo.astype(jnp.int64), hi.astype(jnp.int64)


def candidates(setups: list[FaceSetup], keys: np.ndarray, resolution: int,
               select: list[np.ndarray] | None = None, mode: str | None = None,
               inner_test: str = "corners", tau: float = 0.0, eps: float = EPS64
               ) -> tuple[np.ndarray, np.ndarray]:
    """(triangle, key index) pairs whose texel is in a triangle's box, and with a
    ``mode`` only in the columns of each row that can pass its coverage test
    (:func:`row_spans`).

    Args:
        setups: one :class:`FaceSetup` per face (face f's keys start at f R R).
        keys: int64 [K] sorted unique texel keys to rasterize over.
        select: optional per-face bool [T] triangles to draw (default all).
        mode, inner_test, tau: the coverage test the candidates are for (None: every
            texel of the box); eps: the relative rounding of its evaluation dtype.
    Returns:
        tri int64 [F], slot int64 [F] (index into ``keys``), sorted by face, triangle.
    """
    _, tri, first, count = row_segments(setups, keys, resolution, select, mode, inner_test,
                                        tau, eps)
    return np.repeat(tri, count), np.repeat(first, count) + run_offsets(count)


@dataclasses.dataclass(frozen=True, eq=False)
class Fragments:
    """Fragments of a :func:`raster` call, as JAX arrays padded to a static capacity.

    Attributes:
        tri: int64 [C] triangle; slot: int32 [C] index into the raster's keys (0 on the
            padding);
        covered: bool [C] the coverage test passed (False on the padding);
        lo, hi, centre: float64 [C] the depth plane's min, max and centre over the texel;
        slope: float64 [C] max(|d delta / du|, |d delta / dv|) (per texel);
        depth_class: int8 [C] against the call's ``depth_limit`` [K] of each key:
            :data:`NOT_COVERED` (and the padding), :data:`BEYOND_LIMIT` (covered, ``lo``
            at or beyond its key's limit) or :data:`NEARER` (covered, ``lo`` nearer);
        candidates: the exact number of candidate fragments (the rest is padding);
        host_segment: int32 [candidates] each fragment's row segment, and
        segment_tri: int64 [M] each segment's triangle, host copies of what the fill
            read (:meth:`host_tri_slot`); host_slot: int32 [candidates] the key index.

    A field that the :func:`raster` call did not ask for is None.
    """

    tri: jax.Array | None
    slot: jax.Array | None
    covered: jax.Array | None
    lo: jax.Array | None
    hi: jax.Array | None
    centre: jax.Array | None
    slope: jax.Array | None
    depth_class: jax.Array | None
    candidates: int
    host_segment: np.ndarray
    segment_tri: np.ndarray
    host_slot: np.ndarray

    def host_tri_slot(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """int64 triangle and key index of the fragments ``index`` [N] (< candidates),
        from the host arrays (no device array read)."""
        return (self.segment_tri[self.host_segment[index]],
                self.host_slot[index].astype(np.int64))

    def compact(self, *names: str) -> list[np.ndarray]:
        """NumPy arrays ``names`` of the covered fragments, in candidate order."""
        missing = [n for n in ("covered",) + names if getattr(self, n) is None]
        if missing:
            raise ValueError(f"Fragments.compact: {missing} were not computed; pass them "
                             "in raster(..., fields=...)")
        keep = np.flatnonzero(np.asarray(self.covered))
        return [np.asarray(getattr(self, n))[keep] for n in names]


def x64():
    """The context the raster's float64 JAX bookkeeping runs in (whatever the working
    precision): its arrays are float64 and int64."""
    return jax.enable_x64(True)


#: the per-fragment arrays of :class:`Fragments`, in its order
FRAGMENT_FIELDS = ("tri", "slot", "covered", "lo", "hi", "centre", "slope", "depth_class")
#: the fields :func:`raster` computes by default (all but ``depth_class``, which needs a
#: depth limit)
DEFAULT_FIELDS = tuple(f for f in FRAGMENT_FIELDS if f != "depth_class")
#: values of ``Fragments.depth_class``
NOT_COVERED, BEYOND_LIMIT, NEARER = 0, 1, 2


@functools.partial(jax.jit, static_argnames=("resolution", "mode", "inner_test", "t_cap",
                                             "fields"))
def _raster_kernel(seg, slot, ft, keys, unit, depth, tau, limit, *, resolution, mode,
                   inner_test, t_cap, fields):
    """The fill pass: fragment i (its segment ``seg`` [C] and key index ``slot`` [C], -1
    for padding), its texel, coverage and depth range (see :class:`Fragments`), only the
    arrays ``fields`` (the others are never written: each is a full [C] pass of memory).
    Padding fragments are not covered and have slot 0. ``limit``: float64 [K padded]
    depth limit per key, read only for the field ``depth_class`` (else a dummy [1])."""
    valid = slot >= 0
    slot = jnp.maximum(slot, 0)
    ftv = ft[seg]
    key = keys[slot]
    col, row = key % resolution, (key // resolution) % resolution
    plane = depth[ftv]
    cov = coverage(unit[ftv], None, col, row, mode, inner_test, tau, xp=jnp) & valid
    lo, hi, centre = depth_range(plane, col, row, xp=jnp)
    slope = jnp.maximum(jnp.abs(plane[:, 0]), jnp.abs(plane[:, 1]))
    out = {"tri": ftv % t_cap, "slot": slot, "covered": cov, "lo": lo, "hi": hi,
           "centre": centre, "slope": slope}
    if "depth_class" in fields:
        nearer = lo < limit[slot]
        out["depth_class"] = jnp.where(cov, jnp.where(nearer, NEARER, BEYOND_LIMIT),
                                       NOT_COVERED).astype(jnp.int8)
    return tuple(out[f] for f in fields)


def raster(setups: list[FaceSetup], keys: np.ndarray, resolution: int, mode: str,
           inner_test: str = "corners", tau: float = 0.0,
           select: list[np.ndarray] | None = None,
           fields: tuple[str, ...] = DEFAULT_FIELDS,
           depth_limit: np.ndarray | None = None) -> Fragments:
    """Rasterize over sorted texel ``keys`` [K] in ``mode`` (float64, jit-compiled).
    ``fields``: the :class:`Fragments` arrays to compute (the rest are None);
    ``depth_limit``: float64 [K] per key, needed by (only) the field ``depth_class``.

    Two phases: the exact candidate count (:func:`row_segments`), then the fill,
    coverage and depth range of every candidate under ``jax.jit`` at a static capacity
    (the candidates padded to one of ``FRAGMENT_BUCKET_STEPS`` sizes per octave, the
    segments, the keys and the triangles to powers of two, so shapes repeat across
    frames; nothing is truncated). Call inside :func:`x64`.
    """
    if not jax.config.jax_enable_x64:
        # the spans' rounding slack is sized for the float64 test
        raise RuntimeError("light_raster.raster runs inside light_raster.x64() (its fill "
                           "and coverage test are float64)")
    unknown = sorted(set(fields) - set(FRAGMENT_FIELDS))
    if unknown:
        raise ValueError(f"light_raster.raster: unknown fragment fields {unknown}; allowed: "
                         f"{', '.join(FRAGMENT_FIELDS)}")
    ordered = tuple(f for f in FRAGMENT_FIELDS if f in fields)     # one compiled order
    if ("depth_class" in fields) != (depth_limit is not None):
        raise ValueError("light_raster.raster: the field 'depth_class' and the argument "
                         "depth_limit come together (one without the other was given)")
    face, tri, first, count = row_segments(setups, keys, resolution, select, mode,
                                           inner_test, tau, EPS64)
    t_cap = bucket(max(len(s.unit) for s in setups), minimum=16)
    unit = np.zeros((len(setups) * t_cap, 3, 3))
    depth = np.zeros((len(setups) * t_cap, 3))
    for f, s in enumerate(setups):
        unit[f * t_cap: f * t_cap + len(s.unit)] = s.unit
        depth[f * t_cap: f * t_cap + len(s.depth)] = s.depth
    total = int(count.sum())
    m_cap = bucket(len(count), minimum=256)
    capacity = bucket(total, steps=FRAGMENT_BUCKET_STEPS)
    # fragments are numbered, and index segments and keys, in int32
    check_int32(max(m_cap, len(keys), capacity), "light-raster fragments, row segments and "
                "texel keys", "use a smaller light resolution or fewer casters")
    # each fragment's segment and key index, expanded on the host: a scatter of the run
    # starts and a scan over the capacity cost XLA on the CPU more than np.repeat (the
    # slots are np.repeat(first, count) + run_offsets(count), in int32 without the
    # int64 temporaries)
    seg = np.zeros(capacity, np.int32)
    seg[:total] = np.repeat(np.arange(len(count), dtype=np.int32), count)
    slot = np.full(capacity, -1, np.int32)
    slot[:total] = np.repeat((first - (np.cumsum(count) - count)).astype(np.int32), count)
    slot[:total] += np.arange(total, dtype=np.int32)
    k_cap = bucket(len(keys))
    limit = (jnp.zeros(1) if depth_limit is None else
             jnp.asarray(pad(np.asarray(depth_limit, np.float64), k_cap)))
    out = _raster_kernel(
        jnp.asarray(seg), jnp.asarray(slot), jnp.asarray(pad(face * t_cap + tri, m_cap)),
        jnp.asarray(pad(keys, k_cap)), jnp.asarray(unit), jnp.asarray(depth),
        jnp.asarray(tau, jnp.float64), limit, resolution=int(resolution), mode=mode,
        inner_test=inner_test, t_cap=t_cap, fields=ordered)
    computed = dict(zip(ordered, out))
    return Fragments(**{f: computed.get(f) for f in FRAGMENT_FIELDS}, candidates=total,
                     host_segment=seg[:total], segment_tri=tri, host_slot=slot[:total])


def _distance(values, norms, xp):
    """Signed distance in texels; +-inf for an edge whose line is at infinity.
    ``norms=None``: the rows are already unit rows (``FaceSetup.unit``)."""
    if norms is None:
        return values
    safe = xp.where(norms > 0, norms, 1)
    big = xp.where(values >= 0, xp.inf, -xp.inf)
    return xp.where(norms > 0, values / safe, big)


def coverage(edges, norms, col, row, mode: str, inner_test: str = "corners", tau=0.0,
             xp=np):
    """bool [F]: does the triangle of each fragment cover texel (col, row) in ``mode``?

    Args:
        edges: [F, 3, 3] edge rows of each fragment's triangle; norms: [F, 3] their
            gradient lengths, or None when ``edges`` are unit rows (``FaceSetup.unit``);
            col, row: int [F] texel.
        mode: "standard" (centre, top-left rule), "inner" (closed square inside, at
            least ``tau`` texels from every edge; ``inner_test`` "corners" or "circle"),
            "outer" (closed square within ``tau`` texels of every edge's inside).
        tau: margin in texels (scalar or [F]).

    An edge function is affine, so its smallest and largest values over the square are
    at corners: the centre value -+ (|a| + |b|) / 2 (one evaluation per edge).
    """
    a, b = edges[..., 0], edges[..., 1]
    u = col.astype(edges.dtype)[:, None] + 0.5
    v = row.astype(edges.dtype)[:, None] + 0.5
    centre = a * u + b * v + edges[..., 2]
    if mode == "standard":
        top_left = (a > 0) | ((a == 0) & (b > 0))
        return xp.all((centre > 0) | ((centre == 0) & top_left), axis=-1)
    s, sign_tau, const = coverage_terms(mode, inner_test)
    tau = xp.asarray(tau, dtype=edges.dtype)
    tau = tau[:, None] if tau.ndim == 1 else tau
    half = 0.5 * (xp.abs(a) + xp.abs(b))
    if s:
        centre = centre + half if s > 0 else centre - half
    thr = -tau if sign_tau < 0 else const + tau      # inner and outer: sign_tau != 0
    return xp.all(_distance(centre, norms, xp) >= thr, axis=-1)


def coverage_terms(mode: str, inner_test: str = "corners") -> tuple[int, int, float]:
    """(s, sign_tau, const): ``mode``'s coverage test passes where, for every edge, the
    signed distance (texels) of ``centre + s * half`` is at least ``const + sign_tau *
    tau`` (``centre`` the edge function at the texel centre, ``half`` its half range over
    the square). For "standard" (centre inside, top-left ties; no margin) the terms of
    the test with ties included and tau ignored, which passes a superset of its texels."""
    if mode == "outer":
        return 1, -1, 0.0           # some corner within tau of the inside
    if mode == "inner":
        if inner_test == "corners":
            return -1, 1, 0.0       # every corner tau inside
        return 0, 1, HALF_DIAGONAL  # the circumscribed circle tau inside
    if mode == "standard":
        return 0, 0, 0.0
    raise ValueError(f"light raster mode must be one of {MODES}, got {mode!r}")


def depth_range(depth, col, row, xp=np):
    """(min [F], max [F], centre [F]) of the depth plane [F, 3] over each texel square."""
    a, b = depth[:, 0], depth[:, 1]
    centre = a * (col.astype(depth.dtype) + 0.5) + b * (row.astype(depth.dtype) + 0.5) + depth[:, 2]
    half = 0.5 * (xp.abs(a) + xp.abs(b))
    return centre - half, centre + half, centre


def program1_covered(edges, vertex_w, absdet, col, row, xp=np):
    """bool [F]: the poster's Program 1 on screen-space barycentrics (front triangles).

    The screen-space (noperspective) barycentrics gamma_i = w_i A_i . (u, v, 1) / |D| are
    affine in (u, v) and sum to 1 (w_i the vertices' homogeneous w [F, 3], |D| [F]).
    Program 1 keeps a texel when, at its centre, gamma_0 >= max(|a_0|, |b_0|), gamma_1 >=
    max(|a_1|, |b_1|) and 1 - gamma_0 - gamma_1 >= max(|a_0 + a_1|, |b_0 + b_1|), with
    a = dx + dy, b = dx - dy and dx, dy half the per-texel derivatives. Equal to the
    corners test away from exact ties (the tests compare the two).
    """
    k = vertex_w / absdet[:, None]                          # [F, 3]
    u = col.astype(edges.dtype) + 0.5
    v = row.astype(edges.dtype) + 0.5
    g = k * (edges[..., 0] * u[:, None] + edges[..., 1] * v[:, None] + edges[..., 2])
    dx, dy = 0.5 * k * edges[..., 0], 0.5 * k * edges[..., 1]
    a, b = dx + dy, dx - dy
    ok0 = g[:, 0] >= xp.maximum(xp.abs(a[:, 0]), xp.abs(b[:, 0]))
    ok1 = g[:, 1] >= xp.maximum(xp.abs(a[:, 1]), xp.abs(b[:, 1]))
    ok2 = 1 - g[:, 0] - g[:, 1] >= xp.maximum(xp.abs(a[:, 0] + a[:, 1]), xp.abs(b[:, 0] + b[:, 1]))
    return ok0 & ok1 & ok2


def rasterize(camera: LightCamera, triangles: np.ndarray, mode: str,
              inner_test: str = "corners", tau: float = 0.0, keys: np.ndarray | None = None,
              dtype=np.float64, xp=np, pad: float = 1.0):
    """All fragments of ``triangles`` [T, 3, 3] on ``camera`` in ``mode``.

    Args:
        keys: sorted texel keys to rasterize over (default every texel of every face).
        dtype: evaluation dtype (the set-up is float64, then cast).
        pad: texels around each triangle's box (:func:`setup_face`).
    Returns:
        tri int64 [N], key int64 [N] of the covered fragments, and the per-face set-ups.
    """
    r = int(camera.resolution[0])
    if keys is None:
        keys = np.arange(len(camera.faces) * r * r, dtype=np.int64)
    setups = [setup_face(f, triangles, pad) for f in camera.faces]
    tri, slot = candidates(setups, keys, r, None, mode, inner_test, tau,
                           float(np.finfo(dtype).eps))
    key = keys[slot]
    face = key // (r * r)
    col, row = key % r, (key // r) % r
    edges = np.stack([s.unit for s in setups])[face, tri].astype(dtype)
    cov = np.asarray(coverage(edges, None, col, row, mode, inner_test, tau, xp=np))
    return tri[cov], key[cov], setups


def unique_keys(key: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True)`` of texel keys ``key`` [N] in [0, size):
    the sorted distinct keys [K] and each key's index [N] (int64). Counts occupancy in a
    table of ``size`` entries instead of sorting when that table is small (size <= 4 N)."""
    key = np.asarray(key, dtype=np.int64)
    if size > 4 * len(key):
        keys, inv = np.unique(key, return_inverse=True)
        return keys, inv.astype(np.int64, copy=False)
    present = np.bincount(key, minlength=size) > 0
    return np.flatnonzero(present), (np.cumsum(present) - 1)[key]


def rounding_margin(dtype, points: np.ndarray, texel_world: float) -> float:
    """Texels covering ``dtype`` rounding of world coordinates of magnitude ``points``:
    ``64 eps max|x| / texel_world`` (``texel_world``: the smallest world size of a texel
    at the points)."""
    scale = float(np.abs(np.asarray(points, dtype=np.float64)).max(initial=1.0))
    return 64.0 * float(np.finfo(dtype).eps) * scale / max(texel_world, 1e-300)


def project_points(camera: LightCamera, points: np.ndarray, with_depth: bool = False):
    """Light-space coordinates of world ``points`` [N, 3] (float64).

    Returns:
        face int32 [N], uv float64 [N, 2] (texel coordinates), key int64 [N] (the
        texel, :func:`texel_keys`), delta float64 [N] (the face's depth convention), and
        with ``with_depth`` the depth float64 [N] along the face's axis (world units).
    """
    face, uv, depth = camera.to_texels(points)
    if len(camera.faces) == 1:
        delta = face_depth(camera.faces[0], depth)
    else:
        delta = np.empty(len(face))
        for f in np.unique(face):
            sel = face == f
            delta[sel] = face_depth(camera.faces[f], depth[sel])
    out = face, uv, texel_keys(face, uv, camera.resolution[0]), delta
    return out + (depth,) if with_depth else out


def texel_world_size(camera: LightCamera, points: np.ndarray | None = None, *,
                     face: np.ndarray | None = None,
                     depth: np.ndarray | None = None) -> np.ndarray:
    """float64 [N]: world size of one texel at ``points`` [N, 3] (the texel side times
    the depth on perspective faces), or at points already projected (``face``, ``depth``
    of :meth:`LightCamera.to_texels`)."""
    if points is not None:
        face, _, depth = camera.to_texels(points)
    size = np.array([f.texel_size for f in camera.faces])[face]
    return size if camera.kind == "orthographic" else size * depth
