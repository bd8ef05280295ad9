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

Everything here is jit-compatible, uses uint32 with logical shifts, and has no Python
int literal above 2**31 in traced code.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

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
    if g.per_word == 1:
        return rows
    r = rows.reshape(rows.shape[:-1] + (g.words, 2))
    return jax.lax.shift_left(r[..., 0], jnp.uint32(16)) | r[..., 1]


def popcount(words):
    """int32 [...]: set bits of uint32 words [..., W], summed over the last axis."""
    return jnp.sum(jax.lax.population_count(words).astype(jnp.int32), axis=-1)


def edge_outside_rows(a, b, c, g: Grid):
    """Cells of each scanline *outside* the half-plane a x + b y + c >= 0.

    Args:
        a, b, c: float arrays [...] (any float dtype), one edge function each.
    Returns:
        uint32 [..., rows]: bit set = cell centre outside the edge's half-plane
        (a cell centre exactly on the edge is inside).
    """
    xs, ys = g.centres()
    dtype = jnp.result_type(a)
    w = 2.0 / g.cols
    y = jnp.asarray(ys, dtype)
    a = a[..., None]
    f0 = a * (-1.0 + 0.5 * w) + b[..., None] * y + c[..., None]   # f at column 0 [..., rows]
    step = a * w                                                   # f(j+1) - f(j)
    n = g.cols
    safe = jnp.where(step == 0, jnp.ones_like(step), step)
    t = jnp.clip(-f0 / safe, -1.0, n + 1.0)        # inside: j >= t (step > 0), j <= t (< 0)
    t = jnp.where(jnp.isnan(t), jnp.asarray(n + 1.0, dtype), t)
    first_in = jnp.clip(jnp.ceil(t), 0, n).astype(jnp.uint32)          # step > 0
    first_out = jnp.clip(jnp.floor(t) + 1, 0, n).astype(jnp.uint32)    # step < 0
    full = jnp.uint32(g.full_row)
    left = full ^ shr(full, first_in)               # columns 0 .. first_in-1
    right = shr(full, first_out)                    # columns first_out .. n-1
    flat = jnp.where(f0 < 0, full, jnp.uint32(0))
    return jnp.where(step > 0, left, jnp.where(step < 0, right, flat))


def polygon_keep_rows(edges, g: Grid, active=None):
    """Rows to AND into the grid for a convex polygon given by its edges.

    Args:
        edges: float [..., E, 3], edge functions (a, b, c): inside where all
            a x + b y + c >= 0.
        active: optional bool [...]; inactive polygons keep every bit.
    Returns:
        uint32 [..., rows]: bits cleared exactly at cell centres inside the polygon.
    """
    out = edge_outside_rows(edges[..., 0, 0], edges[..., 0, 1], edges[..., 0, 2], g)
    for e in range(1, edges.shape[-2]):
        out = out | edge_outside_rows(edges[..., e, 0], edges[..., e, 1], edges[..., e, 2], g)
    if active is not None:
        out = jnp.where(active[..., None], out, jnp.uint32(g.full_row))
    return out


def visibility(words, g: Grid):
    """float [...]: set bits of the grid words [..., W] over the disk's bit count."""
    return popcount(words).astype(jnp.float32) / np.float32(g.disk_bits)


# ------------------------------------------------------------------ projections

def triangle_edges_2d(p):
    """Edge functions of 2-D triangles, oriented so the inside is >= 0.

    Args:
        p: float [..., 3, 2], vertices in disk space.
    Returns:
        edges float [..., 3, 3] (a, b, c) and ok bool [...] (non-zero signed area).
    """
    q = jnp.roll(p, -1, axis=-2)                     # p_{i+1}
    ex = q[..., 0] - p[..., 0]
    ey = q[..., 1] - p[..., 1]
    # f_i(x, y) = ex * (y - p_y) - ey * (x - p_x)  (>= 0 left of the edge)
    a = -ey
    b = ex
    c = ey * p[..., 0] - ex * p[..., 1]
    area = jnp.sum(p[..., 0] * q[..., 1] - q[..., 0] * p[..., 1], axis=-1)
    sign = jnp.sign(area)[..., None]
    edges = jnp.stack([a * sign, b * sign, c * sign], axis=-1)
    return edges, area != 0


def project_paper(d, s):
    """The paper's projection of light-frame vectors into disk space.

    Args:
        d: float [..., 3] (x, y, z), +z towards the light, world units.
        s: float scalar or [...] broadcastable, the disk scale (sin or tan of the radius).
    Returns:
        float [..., 2]: ``d.xy / max(1e-4, s * |d.z|)``.
    """
    den = jnp.maximum(PAPER_CLAMP, s * jnp.abs(d[..., 2]))
    return d[..., :2] / den[..., None]


def homogeneous_edges(d, s, n_recv, eps, z_light=None):
    """Exact disk-space edge functions of triangles seen from the fragment.

    A disk point (x, y) is the direction u = (s x, s y, 1). Inside = the ray from the
    fragment along u meets the triangle, at a point at least ``eps`` above the
    receiver's tangent plane and (if ``z_light`` is given) not beyond the light's
    silhouette disk at light-frame depth ``z_light``.

    Args:
        d: float [..., 3, 3], triangle vertices minus the fragment, light frame.
        s: disk scale, scalar or [...].
        n_recv: float [..., 3], the receiver's unit normal in the light frame.
        eps: receiver bias, world units (scalar).
        z_light: None (sun) or float [...], depth of the silhouette disk's plane.
    Returns:
        edges float [..., E, 3] with E = 4 (sun) or 5 (sphere), ok bool [...]
        (the fragment is not in the triangle's plane).
    """
    d0, d1, d2 = d[..., 0, :], d[..., 1, :], d[..., 2, :]
    m = jnp.stack([jnp.cross(d0, d1), jnp.cross(d1, d2), jnp.cross(d2, d0)], axis=-2)
    det = jnp.sum(d2 * m[..., 0, :], axis=-1)             # det(d0, d1, d2)
    sg = jnp.sign(det)
    s = jnp.asarray(s)

    def lin(v, scale):                                     # v . u as (a, b, c)
        return jnp.stack([scale * v[..., 0], scale * v[..., 1], v[..., 2]], axis=-1)

    s_e = s[..., None] if s.ndim else s                    # broadcast over the 3 edges
    rows = [lin(m * sg[..., None, None], s_e)]
    # hit point h = u * det / (n_t . u), n_t = (d1 - d0) x (d2 - d0), n_t . d0 = det.
    n_t = jnp.cross(d1 - d0, d2 - d0)
    # n_recv . h >= eps  <=>  |det| (n_recv . u) - eps sg (n_t . u) >= 0
    v = jnp.abs(det)[..., None] * n_recv - eps * sg[..., None] * n_t
    rows.append(lin(v, s)[..., None, :])
    if z_light is not None:
        # h_z <= z_light  <=>  sg (z_light (n_t . u) - det) >= 0
        lv = lin(z_light[..., None] * n_t, s)
        lv = lv.at[..., 2].add(-det)
        rows.append((lv * sg[..., None])[..., None, :])
    return jnp.concatenate(rows, axis=-2), det != 0


def horizon_edge(n_recv, s):
    """Edge (a, b, c) [..., 3] of the disk part above the receiver's tangent plane."""
    return jnp.stack([s * n_recv[..., 0], s * n_recv[..., 1], n_recv[..., 2]], axis=-1)


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
