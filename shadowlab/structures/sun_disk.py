"""Sun-disk primitives of tiled per-triangle soft shadows (Kalbertodt 2023).

Disk space: the light's disk seen from a fragment, centre (0, 0), radius 1. A
direction from the fragment with light-frame coordinates (x, y, z) (+z towards the
light's centre) lands at (x, y) / (s * z), s = tan of the disk's angular radius
(``s = sin`` in the paper; the two differ by cos(r), 1 - 1.1e-5 at the sun's 0.27 deg).

A *grid* covers the square [-1, 1]^2 with ``cols`` x ``rows`` cells. A cell is a bit;
a set bit is light that reaches the fragment; a cell belongs to the disk when its
centre lies in the closed unit disk. Visibility = set bits / disk bits. Rows are
scanlines: row r has centre y_r = -1 + (r + 1/2) * 2 / rows, column j centre
x_j = -1 + (j + 1/2) * 2 / cols; column 0 is the most significant bit of its row.

- ``16x16``: 16 rows of 16 bits, two rows per uint32 word (row 2k in the high half of
  word k), eight words; the disk holds 208 cells, the paper's constants
  ``0x07e01ff8, 0x3ffc7ffe, 0x7ffeffff, 0xffffffff, ...``.
- ``31xN`` (N = 3, 5, 7, 15, 31): one row of 31 bits per word, so every shift is by
  0..31 and the full-row constant 2**31 - 1 fits a non-negative int32.

Rasterization (the paper's per-scanline edge-mask trick, evaluated at cell centres):
a convex polygon is given by edge functions f_e(x, y) = a_e x + b_e y + c_e, inside
where every f_e >= 0 (inclusive). On scanline y the cells inside edge e form a prefix
or a suffix of the row, found from one division; the cells *outside* edge e are one
logical shift of the full row. OR-ing the outside masks of all edges gives a row with
bits cleared exactly inside the polygon, which is AND-ed into the grid. The cost per
scanline is constant, whatever the polygon's size. Overlapping occluders therefore
unite (two triangles covering the same half give 50 %, not 100 %), unlike the naive
sum of analytic overlap areas (:func:`overlap_area`), kept as a comparison.

Projections (see docs/soft_tiled.md):

- ``paper``: vertices d (light frame, relative to the fragment) go to
  ``d.xy / max(1e-4, s * |d.z|)`` and the polygon is the 2-D triangle of the projected
  vertices (clamp and abs() as in the paper: exact when every vertex is in front of the
  fragment by more than ``1e-4 / s``).
- ``homogeneous``: the edge functions come straight from 3-D: the ray from the fragment
  along u = (s x, s y, 1) meets the triangle iff u . (d_i x d_{i+1}) has the sign of
  det(d0, d1, d2) for all three edges (homogeneous rasterization); no divide, no
  clamp, no abs, exact for vertices behind the fragment. Two more linear edges clip the
  hit point to at least ``eps`` above the receiver's tangent plane (the reference's
  receiver bias) and, for a sphere light, in front of the light's silhouette disk.

Rounding: every value that decides a bit (projection, edge functions, the per-row
crossing values, orientation) is rounded the same way in any surrounding program:
products go through ``core.numerics.opaque_mul`` (an integer OR with a zero XLA cannot prove to
be zero, so no product is fused into a following add), sums are explicit ordered adds,
divisions true divisions of same-shaped arrays, orientation flips negations. The Warp
kernel (``kernels/sun_disk.py``) repeats these plain operations in the same order and
equals this code bit for bit, exact ties included.

Everything here is jit-compatible, uses uint32 with logical shifts, and has no Python
int literal above 2**31 in traced code.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..core.numerics import opaque_mul, opaque_zero

PAPER_CLAMP = 1e-4          # the paper's max(0.0001, sin(r) * |z|)
PAPER_DISK_16X16 = (0x07E01FF8, 0x3FFC7FFE, 0x7FFEFFFF, 0xFFFFFFFF,
                    0xFFFFFFFF, 0xFFFF7FFE, 0x7FFE3FFC, 0x1FF807E0)
GRID_NAMES = ("16x16", "31x3", "31x5", "31x7", "31x15", "31x31")


@dataclasses.dataclass(frozen=True)
class Grid:
    """A bitmask grid over the disk's bounding square [-1, 1]^2.

    Attributes:
        name: ``"16x16"`` or ``"31xN"``.
        cols: cells per row (16 or 31); rows: scanlines; per_word: rows per uint32 word.
    """

    name: str
    cols: int
    rows: int
    per_word: int

    @property
    def words(self) -> int:
        return self.rows // self.per_word

    @property
    def full_row(self) -> np.uint32:
        return np.uint32((1 << self.cols) - 1)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates: x [cols] and y [rows], float64, in disk space."""
        x = -1 + (np.arange(self.cols) + 0.5) * 2 / self.cols
        y = -1 + (np.arange(self.rows) + 0.5) * 2 / self.rows
        return x, y

    def disk_cells(self) -> np.ndarray:
        """bool [rows, cols]: cells whose centre lies in the closed unit disk."""
        x, y = self.centres()
        return x[None, :] ** 2 + y[:, None] ** 2 <= 1.0

    def disk_rows(self) -> np.ndarray:
        """uint32 [rows]: the disk cells of each row (column 0 = bit cols-1)."""
        return cells_to_rows(self.disk_cells())

    def disk_mask(self) -> np.ndarray:
        """uint32 [words]: the packed disk mask the grid is initialised to."""
        return pack_rows_np(self.disk_rows(), self)

    @property
    def disk_bits(self) -> int:
        return int(self.disk_cells().sum())


def grid(name: str) -> Grid:
    """The grid called ``name`` (one of ``GRID_NAMES``)."""
    if name == "16x16":
        return Grid(name, 16, 16, 2)
    cols, _, rows = name.partition("x")
    if cols != "31" or not rows.isdigit() or name not in GRID_NAMES:
        raise ValueError(f"unknown grid {name!r}; allowed: {', '.join(GRID_NAMES)}")
    return Grid(name, 31, int(rows), 1)


def cells_to_rows(cells: np.ndarray) -> np.ndarray:
    """bool [..., rows, cols] -> uint32 [..., rows] (column 0 = the top bit)."""
    cols = cells.shape[-1]
    weights = (np.uint64(1) << np.arange(cols - 1, -1, -1, dtype=np.uint64))
    return (cells.astype(np.uint64) * weights).sum(-1).astype(np.uint32)


def rows_to_cells(rows: np.ndarray, cols: int) -> np.ndarray:
    """uint32 [..., rows] -> bool [..., rows, cols]."""
    shifts = np.arange(cols - 1, -1, -1, dtype=np.uint32)
    return ((np.asarray(rows, np.uint32)[..., None] >> shifts) & np.uint32(1)).astype(bool)


def pack_rows_np(rows: np.ndarray, g: Grid) -> np.ndarray:
    """NumPy twin of :func:`pack_rows`: uint32 [..., rows] -> [..., words]."""
    rows = np.asarray(rows, np.uint32)
    if g.per_word == 1:
        return rows
    r = rows.reshape(rows.shape[:-1] + (g.words, 2))
    return (r[..., 0] << np.uint32(16)) | r[..., 1]


def unpack_words_np(words: np.ndarray, g: Grid) -> np.ndarray:
    """uint32 [..., words] -> [..., rows]."""
    words = np.asarray(words, np.uint32)
    if g.per_word == 1:
        return words
    hi = words >> np.uint32(16)
    lo = words & np.uint32(0xFFFF)
    return np.stack([hi, lo], -1).reshape(words.shape[:-1] + (g.rows,))


# ------------------------------------------------------------------ rounding helpers

def _flip(x, neg):
    """-x where ``neg``, else x (orientation flips as negations: exact, no product)."""
    return jnp.where(neg, -x, x)


# ------------------------------------------------------------------ traced bit operations

def shr(x, k):
    """Logical right shift of uint32 ``x`` by ``k`` in [0, 32]; a shift by 32 gives 0.

    (XLA's shift by >= the bit width is defined as 0 for logical shifts, but GPU
    shading languages leave it undefined; the select makes the intent explicit.)
    """
    k = jnp.asarray(k, jnp.uint32)
    shifted = jax.lax.shift_right_logical(jnp.asarray(x, jnp.uint32), jnp.minimum(k, 31))
    return jnp.where(k >= 32, jnp.uint32(0), shifted)


def pack_rows(rows, g: Grid):
    """uint32 [..., rows] -> uint32 [..., words] (16x16: row 2k in the high half)."""
    return jnp.stack(pack_list([rows[..., r] for r in range(g.rows)], g), -1)


def pack_list(rows: list, g: Grid) -> list:
    """Rows (a list of uint32 arrays) -> words (a list): 16x16 packs two rows a word."""
    if g.per_word == 1:
        return list(rows)
    return [jax.lax.shift_left(rows[2 * k], jnp.uint32(16)) | rows[2 * k + 1]
            for k in range(g.words)]


def popcount(words):
    """int32 [...]: set bits of uint32 words [..., W], summed over the last axis."""
    return jnp.sum(jax.lax.population_count(words).astype(jnp.int32), axis=-1)


def popcount_list(words: list):
    """int32 [...]: set bits summed over a list of uint32 word arrays."""
    out = jax.lax.population_count(words[0]).astype(jnp.int32)
    for wd in words[1:]:
        out = out + jax.lax.population_count(wd).astype(jnp.int32)
    return out


# The hot paths below work on lists of same-shaped arrays (structure of arrays): XLA's
# CPU backend fuses long elementwise chains over a large minor axis into one loop, but
# vectorizes badly over small trailing axes (3 vertices, 16 rows). The array versions
# (edge_outside_rows, polygon_keep_rows, ...) wrap them for tests and notebooks.

def edge_outside_list(a, b, c, g: Grid, zero=None) -> list:
    """Cells of each scanline *outside* the half-plane a x + b y + c >= 0.

    On row r the edge function at column j is f0_r + A j (A = a * cell width); the
    columns inside are j >= t_r (A > 0) or j <= t_r (A < 0), t_r = -f0_r / A, linear in
    the row's y: one division per edge, a multiply and an add per row. The first column
    inside (A > 0: ceil t) or outside (A < 0: floor t + 1) is a shift in [0, cols],
    cols <= 31, so no shift by 32 arises.

    Rounding (the kernel repeats it): step = a w, base = a (-1 + w/2) + c,
    inv = -1 / step (true division), t0 = base inv, dt = b inv, t_r = t0 + dt y_r; a
    flat edge (step == 0) tests base + b y_r < 0. Every product is opaque.

    Args:
        a, b, c: float arrays [...] (same shape and dtype), one edge function each.
        zero: int 0 [] from ``core.numerics.opaque_zero`` (computed from ``a`` if None).
    Returns:
        ``rows`` uint32 arrays [...]: bit set = cell centre outside the edge's
        half-plane (a cell centre exactly on the edge is inside).
    """
    if zero is None:
        zero = opaque_zero(a, jnp.int32)

    def mul(x, y):
        return opaque_mul(x, y, zero)

    _, ys = g.centres()
    w = 2.0 / g.cols
    n = g.cols
    step = mul(a, w)                                              # f(j+1) - f(j)
    base = mul(a, -1.0 + 0.5 * w) + c                             # f at column 0, y = 0
    flat = step == 0
    inv = jnp.where(flat, 0.0, -1.0 / jnp.where(flat, 1.0, step))
    t0 = mul(base, inv)
    dt = mul(b, inv)
    rising = step > 0
    full = jnp.uint32(g.full_row)
    out = []
    for y in ys:
        t = jnp.clip(t0 + mul(dt, float(y)), -1.0, n + 1.0)
        t = jnp.where(t != t, float(n + 1), t)                     # NaN guard
        k = jnp.where(rising, jnp.ceil(t), jnp.floor(t) + 1.0)
        k = jnp.clip(k, 0.0, float(n)).astype(jnp.uint32)
        tail = jax.lax.shift_right_logical(full, k)                # columns k .. n-1
        sloped = jnp.where(rising, full ^ tail, tail)
        level = jnp.where(base + mul(b, float(y)) < 0, full, jnp.uint32(0))
        out.append(jnp.where(flat, level, sloped))
    return out


def edge_outside_rows(a, b, c, g: Grid, zero=None):
    """Array version of :func:`edge_outside_list`: uint32 [..., rows]."""
    a, b, c = jnp.broadcast_arrays(a, b, c)
    return jnp.stack(edge_outside_list(a, b, c, g, zero), -1)


def polygon_keep_list(edges: list, g: Grid, active=None, zero=None) -> list:
    """Rows to AND into the grid for a convex polygon.

    Args:
        edges: list of (a, b, c) arrays [...]: inside where all a x + b y + c >= 0.
        active: optional bool [...]; inactive polygons keep every bit.
        zero: int 0 [] (``core.numerics.opaque_zero``), shared by all edges (computed if None).
    Returns:
        list of ``rows`` uint32 arrays [...]: bits cleared exactly at the cell centres
        inside the polygon.
    """
    if zero is None:
        zero = opaque_zero(edges[0][0], jnp.int32)
    out = None
    for a, b, c in edges:
        rows = edge_outside_list(a, b, c, g, zero)
        out = rows if out is None else [o | r for o, r in zip(out, rows)]
    if active is not None:
        full = jnp.uint32(g.full_row)
        out = [jnp.where(active, o, full) for o in out]
    return out


def polygon_keep_rows(edges, g: Grid, active=None, zero=None):
    """Array version: edges float [..., E, 3] -> uint32 [..., rows]."""
    lst = [(edges[..., e, 0], edges[..., e, 1], edges[..., e, 2]) for e in range(edges.shape[-2])]
    return jnp.stack(polygon_keep_list(lst, g, active, zero), -1)


def visibility(words, g: Grid):
    """float32 [...]: set bits of the grid words [..., W] over the disk's bit count.

    Computed as popcount * fl(1 / disk_bits) (the reciprocal rounded once on the host),
    which is what XLA makes of the division anyway; written out so the kernel can repeat it.
    """
    inv = np.float32(1.0) / np.float32(g.disk_bits)
    return popcount(words).astype(jnp.float32) * inv


# ------------------------------------------------------------------ projections

def triangle_edges_list(px: list, py: list, zero=None):
    """Edge functions of 2-D triangles, oriented so the inside is >= 0.

    Edge i (from vertex i to i+1): (-ey, ex, ey px_i - ex py_i); the signed area is
    (c_0 + c_1) + c_2 with c_i = px_i py_{i+1} - px_{i+1} py_i; a negative area negates
    the edges. Products opaque.

    Args:
        px, py: three arrays [...] each, the vertices' disk-space coordinates.
        zero: int 0 [] (``core.numerics.opaque_zero``; computed from ``px[0]`` if None).
    Returns:
        edges (a list of three (a, b, c) array triples) and ok bool [...] (non-zero
        signed area; degenerate triangles must be skipped).
    """
    if zero is None:
        zero = opaque_zero(px[0], jnp.int32)

    def mul(x, y):
        return opaque_mul(x, y, zero)

    terms = []
    edges = []
    for i in range(3):
        j = (i + 1) % 3
        ex, ey = px[j] - px[i], py[j] - py[i]
        # f_i(x, y) = ex * (y - p_y) - ey * (x - p_x)  (>= 0 left of the edge)
        edges.append((-ey, ex, mul(ey, px[i]) - mul(ex, py[i])))
        terms.append(mul(px[i], py[j]) - mul(px[j], py[i]))
    area = (terms[0] + terms[1]) + terms[2]
    neg = area < 0
    return [(_flip(a, neg), _flip(b, neg), _flip(c, neg)) for a, b, c in edges], area != 0


def triangle_edges_2d(p, zero=None):
    """Array version: p float [..., 3, 2] -> edges [..., 3, 3], ok [...]."""
    edges, ok = triangle_edges_list([p[..., i, 0] for i in range(3)],
                                    [p[..., i, 1] for i in range(3)], zero)
    return jnp.stack([jnp.stack(e, -1) for e in edges], -2), ok


def project_paper(d, s, zero=None):
    """The paper's projection of light-frame vectors into disk space.

    Args:
        d: float [..., 3] (x, y, z), +z towards the light, world units.
        s: float scalar or [...] broadcastable, the disk scale (sin or tan of the radius).
        zero: int 0 [] (``core.numerics.opaque_zero``; computed from ``d`` if None).
    Returns:
        float [..., 2]: ``d.xy / max(1e-4, s * |d.z|)``, as
        :func:`project_paper_list` rounds it.
    """
    x, y = project_paper_list(d[..., 0], d[..., 1], d[..., 2], s,
                              opaque_zero(d, jnp.int32) if zero is None else zero)
    return jnp.stack([x, y], -1)


def project_paper_list(x, y, z, s, zero=None):
    """SoA :func:`project_paper` of one vertex: arrays [...] -> (X, Y).

    inv = 1 / max(1e-4, s |z|) (one true division), X = x inv, Y = y inv (opaque: they
    feed the edge differences). s |z| only feeds the max, so it needs no care.
    """
    if zero is None:
        zero = opaque_zero(x, jnp.int32)
    inv = 1.0 / jnp.maximum(PAPER_CLAMP, s * jnp.abs(z))
    return opaque_mul(x, inv, zero), opaque_mul(y, inv, zero)


def _mul(a, b):
    return a * b


def _cross(u, v, mul=_mul):
    return (mul(u[1], v[2]) - mul(u[2], v[1]), mul(u[2], v[0]) - mul(u[0], v[2]),
            mul(u[0], v[1]) - mul(u[1], v[0]))


def _dot(u, v, mul=_mul):
    return (mul(u[0], v[0]) + mul(u[1], v[1])) + mul(u[2], v[2])


def homogeneous_edges_list(d: list, s, n_recv, eps, z_light=None, zero=None):
    """Exact disk-space edge functions of triangles seen from the fragment (SoA).

    A disk point (x, y) is the direction u = (s x, s y, 1). Inside = the ray from the
    fragment along u meets the triangle, at a point at least ``eps`` above the
    receiver's tangent plane and (if ``z_light`` is given) not beyond the light's
    silhouette disk at light-frame depth ``z_light``.

    Rounding (the kernel repeats it): m_i = d_i x d_{i+1} and n_t = e1 x e2 as
    a_j b_k - a_k b_j, det = (d2x m0x + d2y m0y) + d2z m0z, products opaque; a
    negative det negates (no product by its sign).

    Args:
        d: three vertices, each a tuple of three arrays [...] (x, y, z): vertex minus
            fragment in the light frame, world units.
        s: disk scale, array [...] or scalar.
        n_recv: tuple of three arrays [...], the receiver's unit normal (light frame).
        eps: receiver bias, world units (scalar).
        z_light: None (sun) or array [...], depth of the silhouette disk's plane.
        zero: int 0 [] (``core.numerics.opaque_zero``; computed from ``d[0][0]`` if None).
    Returns:
        edges (a list of 4 (sun) or 5 (sphere) (a, b, c) triples) and ok bool [...]
        (the fragment is not in the triangle's plane).
    """
    if zero is None:
        zero = opaque_zero(d[0][0], jnp.int32)

    def mul(x, y):
        return opaque_mul(x, y, zero)

    m = [_cross(d[0], d[1], mul), _cross(d[1], d[2], mul), _cross(d[2], d[0], mul)]
    det = _dot(d[2], m[0], mul)                            # det(d0, d1, d2)
    neg = det < 0

    def lin(v):                                            # v . u as (a, b, c)
        return (mul(s, v[0]), mul(s, v[1]), v[2])

    edges = [lin(tuple(_flip(mi, neg) for mi in me)) for me in m]
    # hit point h = u * det / (n_t . u), n_t = (d1 - d0) x (d2 - d0), n_t . d0 = det.
    e1 = tuple(d[1][i] - d[0][i] for i in range(3))
    e2 = tuple(d[2][i] - d[0][i] for i in range(3))
    n_t = _cross(e1, e2, mul)
    # n_recv . h >= eps  <=>  |det| (n_recv . u) - eps sg (n_t . u) >= 0
    adet = jnp.abs(det)
    es = jnp.where(neg, -eps, eps).astype(det.dtype)
    edges.append(lin(tuple(mul(adet, n_recv[i]) - mul(es, n_t[i]) for i in range(3))))
    if z_light is not None:
        # h_z <= z_light  <=>  sg (z_light (n_t . u) - det) >= 0
        a, b, c = lin(tuple(mul(z_light, n_t[i]) for i in range(3)))
        edges.append((_flip(a, neg), _flip(b, neg), _flip(c - det, neg)))
    return edges, det != 0


def homogeneous_edges(d, s, n_recv, eps, z_light=None, zero=None):
    """Array version: d [..., 3, 3], n_recv [..., 3] -> edges [..., E, 3], ok [...]."""
    dl = [tuple(d[..., v, i] for i in range(3)) for v in range(3)]
    nl = tuple(n_recv[..., i] for i in range(3))
    s = jnp.broadcast_to(jnp.asarray(s, d.dtype), d.shape[:-2])
    edges, ok = homogeneous_edges_list(dl, s, nl, eps, z_light,
                                       opaque_zero(d, jnp.int32) if zero is None else zero)
    return jnp.stack([jnp.stack(jnp.broadcast_arrays(*e), -1) for e in edges], -2), ok


def horizon_edge_list(n_recv, s, zero=None):
    """Edge (a, b, c) of the disk part above the receiver's tangent plane:
    (s n_x, s n_y, n_z), n_recv a tuple of three arrays [...] (products opaque)."""
    if zero is None:
        zero = opaque_zero(n_recv[2], jnp.int32)
    return (opaque_mul(s, n_recv[0], zero), opaque_mul(s, n_recv[1], zero), n_recv[2])


def horizon_edge(n_recv, s, zero=None):
    """Edge (a, b, c) [..., 3] of the disk part above the receiver's tangent plane."""
    e = horizon_edge_list(tuple(n_recv[..., i] for i in range(3)), s, zero)
    return jnp.stack(jnp.broadcast_arrays(*e), axis=-1)


# ------------------------------------------------------------------ per-pixel rotation

_HASH_MUL1 = np.uint32(0x7FEB352D)
_HASH_MUL2 = np.uint32(0x846CA68B)


def hash_u32(x):
    """A deterministic 32-bit integer hash (lowbias32) of uint32 ``x`` [...]."""
    x = jnp.asarray(x, jnp.uint32)
    x = x ^ jax.lax.shift_right_logical(x, jnp.uint32(16))
    x = x * jnp.uint32(_HASH_MUL1)
    x = x ^ jax.lax.shift_right_logical(x, jnp.uint32(15))
    x = x * jnp.uint32(_HASH_MUL2)
    return x ^ jax.lax.shift_right_logical(x, jnp.uint32(16))


def pixel_angle(index, seed: int = 0, dtype=jnp.float32):
    """Grid rotation angle in [0, 2 pi) for flat pixel indices ``index`` [...] (uint32).

    The top 24 bits of ``hash_u32(index ^ hash_u32(seed))`` give the angle; the same
    pixel and seed always give the same angle.
    """
    h = hash_u32(jnp.asarray(index, jnp.uint32) ^ hash_u32(jnp.uint32(seed)))
    frac = jax.lax.shift_right_logical(h, jnp.uint32(8)).astype(dtype) * (2.0 ** -24)
    return frac * (2 * math.pi)


# ------------------------------------------------------------------ analytic overlap

def overlap_area(p):
    """Area of the unit disk inside a 2-D triangle (the naive method's per-triangle term).

    Sum over the edges (A, B) of the signed area of disk ∩ triangle (0, A, B): the part
    of the edge inside the disk contributes a triangle, the parts outside a sector.

    Args:
        p: float [..., 3, 2], triangle vertices in disk space.
    Returns:
        float [...], in [0, pi] (absolute value: either orientation).
    """
    a = p
    b = jnp.roll(p, -1, axis=-2)
    e = b - a
    ee = jnp.sum(e * e, -1)
    ae = jnp.sum(a * e, -1)
    aa = jnp.sum(a * a, -1)
    disc = ae * ae - ee * (aa - 1.0)
    safe_ee = jnp.where(ee > 0, ee, 1.0)
    root = jnp.sqrt(jnp.maximum(disc, 0.0))
    t1 = jnp.clip((-ae - root) / safe_ee, 0.0, 1.0)
    t2 = jnp.clip((-ae + root) / safe_ee, 0.0, 1.0)
    hit = (disc > 0) & (ee > 0)
    t1 = jnp.where(hit, t1, 0.0)
    t2 = jnp.where(hit, t2, 0.0)
    p1 = a + t1[..., None] * e
    p2 = a + t2[..., None] * e

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    def angle(u, v):
        return jnp.arctan2(cross(u, v), jnp.sum(u * v, -1))

    area = 0.5 * (angle(a, p1) + cross(p1, p2) + angle(p2, b))
    return jnp.abs(jnp.sum(area, -1))
