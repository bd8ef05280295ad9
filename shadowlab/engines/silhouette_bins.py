"""Screen bins for the silhouette stencil: which sides and caps each sample tests.

Every crossing the software stencil counts for a sample lies on its view ray (the line
through the eye and its evaluation point q, in front of the eye), so it projects to q's
screen position. A sample therefore only needs the primitives whose screen projection
covers q's:

- a front cap (the triangle T) projects into the hull of T's projected vertices;
- a back cap (point light: T projected from the light to infinity) is crossed where the
  direction ``q'`` lies in the cone from the light through T, which projects into the
  hull of the directions ``X - L`` (a direction projects as the point ``E + d``);
- a side quad (edge AB extruded away from the light) is ``conv(A, B) + cone(D_A, D_B)``
  with ``D_X = L_w X' - L'``, so it projects into the hull of A, B, D_A and D_B;

and in every case the primitive's view rays fill the cone from the eye spanned by those
points and directions (its *generators*: ``X'`` for a point, ``D`` for a direction).
The hull bounds the projection when every generator lies strictly in front of the eye
plane; otherwise (a primitive reaching behind the eye) the projection is not bounded.

Beyond the box, each bin test uses the cone itself: its facet planes through the eye
(pairs of generators with every other generator on one side) are half-planes in screen
space, and a primitive enters only the cells that meet every one of them, padded. A
cone that reaches behind the eye is cut to the samples' screen box that way instead of
going into every cell; a long thin side, whose box covers many cells, enters only those
along it. A primitive whose padded cone misses the samples' box enters no cell.

Bins are screen cells of the central projection ``(x / z, y / z)`` in the camera basis,
about TILE x TILE pixels each, over the core of the samples' projected q (all of them
but a few far outliers, :func:`core_range`); cells at the border extend to infinity
(the cell index is clamped, which is monotone, so a box's clamped cell range still holds
every q inside it, an outlier q included: it lies in its border cell's rectangle, and
a cone cut to the box of all q still meets that rectangle at q). A primitive goes into every cell its
padded bounding box meets. A sample whose q is not in front of the eye plane tests
every primitive.

The padding covers the rounding of the kernels' plane predicates ``q' . (x x y)`` in the
working precision. The kernels form each normal from factors that are inputs or single
roundings of differences of inputs (``A' x (B' - A')`` for ``A' x B'``, ``L' x X'``,
``(L' - L_w A') x (B' - A')``), so the normal's error is a few eps |x| |y| and the
predicate can take the wrong sign only within an angle of about
``c eps (1 + |x| |y| / |x x y|)`` of its plane (c about 9 by a worst-case count of the
roundings, 0.5 measured), which the projection stretches by at most ``1 + r^2`` (r:
distance from the projection centre); the pad is ``PAD_FACTOR`` times that unit over
every predicate of the primitive. Where the count only
takes crossings between the eye and q (ZPASS sides, the caps before q), a primitive
whose nearest point is beyond the farthest q of a block by more than ``DEPTH_MARGIN`` of
that depth is left out of that block's list; where it only takes crossings beyond q
(ZFAIL's true front caps), a cap whose farthest vertex is nearer than the block's
nearest q by more than that margin is left out. A ZPASS side also leaves the list of
every cell over whose rectangle its plane lies deeper than the cell's farthest q by more
than a margin of its own, which covers the rounding of the kernels' tests of that plane
(:func:`_plane_depth_cut`, a hierarchical-z test of the plane; :func:`depth_planes`).

Each facet plane is shifted outwards by the same pad (the region it bounds then holds
every direction within the rounding angle of the cone), and a generator pair whose
plane is ill-conditioned (nearly parallel generators) is not used: dropping a facet only
enlarges the region. Cells are tested as their rectangles, border cells extending to
infinity.

The lists are exact CSR arrays (``starts``, ``lengths`` from the counts, never
truncated). ``tests/test_silhouette.py`` checks that the binned passes equal the full
passes per sample.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ..core.capacity import bucket, check_int32, pad, run_offsets
from ..core.sorting import stable_argsort

TILE = 16           # about TILE x TILE pixels of samples per cell
#: pad = PAD_FACTOR eps ratio 2 (1 + r^2), ratio = 1 + |x| |y| / |x x y| of the factors
#: of each plane predicate (measured worst wrong sign in float32: 0.49 eps ratio,
#: tests/test_silhouette_bins.py::test_plane_predicate_rounding_within_the_pad)
PAD_FACTOR = 16.0
DEPTH_MARGIN = 1.0 / 64.0
#: samples per block (one list) and blocks per batch (one loop) of the binned kernels;
#: a grid with smaller blocks gets proportionally more blocks per batch
BLOCK = 64
BATCH = 128


@dataclasses.dataclass(frozen=True, eq=False)
class SampleGrid:
    """The samples' screen cells and their blocks (S samples, Nc cells, Nb blocks).

    Attributes:
        cell: int64 [S] the cell of each sample's q (Nc: q not in front of the eye or not
            finite).
        lo, scale: (u, v) origin and cells per unit of the grid; shape: (gx, gy). The
            grid spans the core of the projected q (:func:`core_range`); the border
            cells reach infinity, so a q outside the span lies in its clamped cell.
        zmax: float64 [Nb] the farthest q depth of each block (inf where a sample's q
            is not in front of the eye).
        zmin: float64 [Nb] the nearest q depth of each block (-inf where a sample's q
            is not in front of the eye).
        block_cell: int64 [Nb] the cell of each block of B samples.
        slot: int64 [S] each sample's place in the blocks' flat [Nb * B] layout.
        q: [Nb + 1, B, 3] the samples in blocks (working dtype; the last block and
            the tail of each cell's last block are zeros).
        q_box: (u0, u1, v0, v1) the box of every projected q in front of the eye (the
            conservative region of unbounded primitives; None: the grid's span).
        q_len_max: float64 [Nb] the largest |q'| of each block (None: not computed).
        q_len_range: (smallest, largest) |q'| of every sample (float64).
        block_count: int64 [Nb] the samples in each block (None: not computed).
    """

    cell: np.ndarray
    lo: tuple
    scale: tuple
    shape: tuple
    zmax: np.ndarray
    zmin: np.ndarray
    block_cell: np.ndarray
    slot: np.ndarray
    q: np.ndarray
    tile: int = TILE
    q_box: tuple = None
    q_len_max: np.ndarray = None
    q_len_range: tuple = (np.inf, 0.0)
    block_count: np.ndarray = None

    @property
    def block(self) -> int:
        """Samples per block."""
        return self.q.shape[1]

    @property
    def cells(self) -> int:
        return self.shape[0] * self.shape[1]

    def box_corners(self) -> np.ndarray:
        """[4, 2] (u, v) corners of the samples' screen box (all projected q lie in it)."""
        if self.q_box is not None:
            lo, hi = (self.q_box[0], self.q_box[2]), (self.q_box[1], self.q_box[3])
        else:
            lo = self.lo
            hi = [a + (n / sc if sc > 0 else 0.0) for a, n, sc in zip(self.lo, self.shape,
                                                                         self.scale)]
        margin = [1e-9 * (1.0 + abs(a) + abs(h)) for a, h in zip(lo, hi)]
        u = (lo[0] - margin[0], hi[0] + margin[0])
        v = (lo[1] - margin[1], hi[1] + margin[1])
        return np.array([(x, y) for x in u for y in v])

    def cell_edges(self, axis: int) -> tuple[np.ndarray, np.ndarray]:
        """float64 [n] the lower and upper bound of each cell column (axis 0) or row
        (axis 1), widened by a millionth of a cell; the border cells reach infinity. A
        grid of no extent along the axis (its core collapsed to one value: :meth:`index`
        puts every q in the first cell, outliers included) gives every cell the whole
        line."""
        n, lo, sc = self.shape[axis], self.lo[axis], self.scale[axis]
        i = np.arange(n, dtype=np.float64)
        if sc > 0:
            lower, upper = lo + (i - 1e-6) / sc, lo + (i + 1 + 1e-6) / sc
        else:
            lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
        lower[0], upper[-1] = -np.inf, np.inf
        return lower, upper

    def index(self, x: np.ndarray, axis: int) -> np.ndarray:
        """int64 [...]: the clamped cell column (axis 0) or row (axis 1) of u or v x."""
        return np.clip(np.floor((x - self.lo[axis]) * self.scale[axis]), 0,
                       self.shape[axis] - 1).astype(np.int64)


#: the grid spans the projected q between these quantiles, widened by CORE_MARGIN of
#: that range (and never beyond the extreme q): a few q far off screen (a grazing
#: sample's cut point near the eye plane) must not stretch every cell
CORE_QUANTILE = 1e-3
CORE_MARGIN = 0.05


def core_range(x: np.ndarray, extremes: tuple[float, float] | None = None
               ) -> tuple[float, float]:
    """(lo, hi) of the grid along one axis: the [CORE_QUANTILE, 1 - CORE_QUANTILE]
    quantiles of ``x`` widened by CORE_MARGIN of their range, within [min, max]
    (``extremes``: x's (min, max) when the caller has them). With no outliers this is
    (min, max). A performance choice only: the border cells reach infinity, so any span
    bins every q correctly (module docstring)."""
    if len(x) == 0:
        return 0.0, 0.0
    a, b = extremes if extremes is not None else (float(x.min()), float(x.max()))
    p, r = tail_quantiles(x, CORE_QUANTILE)
    margin = CORE_MARGIN * (r - p)
    return max(a, float(p - margin)), min(b, float(r + margin))


#: candidates of a tail kept by a threshold from a strided subsample of this size
TAIL_SUBSAMPLE = 4096


def tail_quantiles(x: np.ndarray, q: float) -> tuple[float, float]:
    """``np.quantile(x, [q, 1 - q])`` (its 'linear' method, the same bits) of finite
    float64 x [n], for a small q: the four order statistics it interpolates are found
    among the candidates below (above) a threshold taken from a strided subsample, so
    the work is one comparison pass per tail instead of a copy and a partition of x
    (about 17 -> 1 ms per axis at 1M samples). Falls back to ``np.quantile`` when a
    threshold keeps too few candidates (never a different answer, only slower)."""
    x = np.asarray(x, np.float64)
    n = len(x)

    def by_numpy():
        return tuple(float(v) for v in np.quantile(x, [q, 1.0 - q]))
    if n < 4 * TAIL_SUBSAMPLE or not 0.0 <= q <= 0.5:
        return by_numpy()
    virtual = (n - 1) * np.array([q, 1.0 - q])      # numpy's 'linear' virtual indices
    prev = np.floor(virtual)
    gamma = virtual - prev
    prev = prev.astype(np.int64)
    nxt = np.minimum(prev + 1, n - 1)
    sub = np.sort(x[:: n // TAIL_SUBSAMPLE])
    m = len(sub)
    # the subsample's order statistics at about 4x the wanted rank plus a margin: the
    # thresholds keep a few thousand candidates, and at least the wanted rank + 2 on all
    # but adversarial inputs (checked below)
    j = min(m - 1, int(4 * q * m) + 16)
    low, high = sub[j], sub[m - 1 - j]
    below = x[x <= low]
    above = x[x >= high]
    k_lo = (int(prev[0]), int(nxt[0]))
    k_hi = (n - 1 - int(nxt[1]), n - 1 - int(prev[1]))   # ranks from the top
    if len(below) <= k_lo[1] or len(above) <= k_hi[1]:
        return by_numpy()
    below = np.partition(below, k_lo)
    above = -np.partition(-above, k_hi)
    a = np.array([below[k_lo[0]], above[k_hi[1]]])       # x_(prev)
    b = np.array([below[k_lo[1]], above[k_hi[0]]])       # x_(next)
    # numpy's lerp: a + (b - a) t, or b - (b - a) (1 - t) where t >= 0.5
    diff = b - a
    out = np.where(gamma >= 0.5, b - diff * (1 - gamma), a + diff * gamma)
    return float(out[0]), float(out[1])


def sample_grid(q: np.ndarray, basis, image_shape: tuple[int, int], tile: int = TILE,
                block: int = BLOCK) -> SampleGrid:
    """Cells and blocks of S evaluation points q [S, 3] (eye-relative, working dtype).

    The grid has about one cell per ``tile`` x ``tile`` pixels over the core of the
    projected q (:func:`core_range`). The samples of a cell fill blocks of ``block``
    (the last one padded with zeros) in order of depth (:func:`_depth_key`), so that a
    block's depth range (the depth cuts' limit) is about as narrow as its cell allows.
    """
    uq, vq, zq = _project_columns(q, basis)
    good = (zq > 0) & np.isfinite(zq) & np.isfinite(uq) & np.isfinite(vq)
    every = bool(good.all())        # the usual case: no masked copies of 1M columns
    shape = (max(1, -(-image_shape[1] // tile)), max(1, -(-image_shape[0] // tile)))
    lo, scale, box = [], [], []
    for x, n in ((uq if every else uq[good], shape[0]),
                 (vq if every else vq[good], shape[1])):
        extremes = (float(x.min()), float(x.max())) if len(x) else (0.0, 0.0)
        a, b = core_range(x, extremes)
        lo.append(a)
        scale.append(n / (b - a) if b > a else 0.0)
        box += list(extremes)
    grid = SampleGrid(None, tuple(lo), tuple(scale), shape, None, None, None, None, None,
                      tile, tuple(box))
    n_cells = shape[0] * shape[1]
    with np.errstate(invalid="ignore"):         # the cells of the bad q are replaced
        cell = grid.index(vq, 1) * shape[0] + grid.index(uq, 0)
    if not every:
        cell[~good] = n_cells
    # by cell, within a cell by depth: two radix sorts of 16-bit keys (the depth as its
    # logarithm in 65,536 steps over the samples' range: ties keep pixel order, and the
    # blocks' depth ranges below are exact whatever the order)
    depth = zq if every else np.where(good, zq, np.inf)
    order = np.argsort(_depth_key(zq, good), kind="stable")
    order = order[np.argsort(cell[order].astype(np.uint16 if n_cells < 65536 else np.int64),
                             kind="stable")]
    # the occupied cells ascending, as in ``order``, and where each one's run starts
    counts = np.bincount(cell, minlength=n_cells + 1)
    cells = np.flatnonzero(counts)
    per_cell = counts[cells]
    first = np.cumsum(per_cell) - per_cell
    nb_cell = -(-per_cell // block)
    rank = np.arange(len(order)) - np.repeat(first, per_cell)
    block_of = np.repeat(np.cumsum(nb_cell) - nb_cell, per_cell) + rank // block
    slot = np.empty(len(q), np.int64)
    slot[order] = block_of * block + rank % block
    n_blocks = int(nb_cell.sum())
    q = np.ascontiguousarray(q)
    qb = np.zeros(((n_blocks + 1) * block, 3), q.dtype)
    # rows moved as single 3-value items (a third of the time of a row scatter)
    row = np.dtype((np.void, 3 * q.dtype.itemsize))
    qb.view(row)[:, 0][slot] = q.view(row)[:, 0]
    # a block's samples are consecutive in ``order``: its depth range by reduceat
    first_of_block = np.flatnonzero(rank % block == 0)
    # a q behind the eye counts as +inf for the farthest depth and -inf for the nearest
    # (such q fill the blocks of the extra cell, and no other q does)
    in_order = depth[order]
    zmax = np.maximum.reduceat(in_order, first_of_block) if len(order) else in_order
    zmin = np.minimum.reduceat(in_order, first_of_block) if len(order) else in_order
    block_cell = np.repeat(cells, nb_cell)
    if not every:
        zmin[block_cell == n_cells] = -np.inf
    length = np.sqrt(sum(np.asarray(q[:, k], np.float64) ** 2 for k in range(3)))
    q_len_max = (np.maximum.reduceat(length[order], first_of_block) if len(order)
                 else length)
    q_len_range = (float(length.min()), float(length.max())) if len(q) else (np.inf, 0.0)
    return dataclasses.replace(grid, cell=cell, zmax=zmax, zmin=zmin,
                               block_cell=block_cell, slot=slot,
                               q=qb.reshape(n_blocks + 1, block, 3), q_len_max=q_len_max,
                               q_len_range=q_len_range,
                               block_count=np.diff(first_of_block, append=len(order)))


def _depth_key(z: np.ndarray, good: np.ndarray) -> np.ndarray:
    """uint16 [S]: log(z) of the samples ``good`` in 65,536 steps over their range (the
    others 65,535), monotone in z."""
    key = np.full(len(z), 65535, np.uint16)
    if good.any():
        lz = np.log(z[good])
        lo, span = float(lz.min()), float(lz.max() - lz.min())
        scale = 65535.0 / span if span > 0 else 0.0
        key[good] = np.minimum((lz - lo) * scale, 65535.0).astype(np.uint16)
    return key


@dataclasses.dataclass(frozen=True, eq=False)
class ScreenBins:
    """Per-cell primitive lists (K primitives, Nc cells plus one 'all' cell).

    Attributes:
        entries: int32 [E] primitive indices (into the K primitives), grouped by cell
            (with a depth cut: in order of nearest depth, or of farthest depth
            descending, within a cell; else in index order); the lists lie column after
            column of cells, the 'all' cell's last.
        starts, lengths: int64 [Nc + 1] each cell's first entry and list length.
        block_lengths: int64 [Nb] the part of its cell's list each block of the grid
            tests (all of it, or with a depth cut the primitives not beyond the block).
        unbounded: int number of primitives whose projection is not bounded (every cell).
        tests: (sample, primitive) pairs the binned pass evaluates.
    """

    entries: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    block_lengths: np.ndarray
    unbounded: int
    tests: int
def _project_columns(p: np.ndarray, basis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float64 (u, v, z) [...] of eye-relative points p [..., 3] (any float dtype), each
    coordinate converted to float64 once, as a column (no [..., 3] float64 copy)."""
    right, up, back = basis
    c = [np.asarray(p[..., k], np.float64) for k in range(3)]
    x, y, z = (c[0] * a[0] + c[1] * a[1] + c[2] * a[2]
               for a in (right, up, -back))      # elementwise: no BLAS call on [S, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return x / z, y / z, z


def _norm(x):
    return np.sqrt(np.einsum("...i,...i->...", x, x))


def _pair_ratio(x: np.ndarray, y: np.ndarray, cross: np.ndarray | None = None) -> np.ndarray:
    """[K]: the pad unit 1 + |x| |y| / |x x y| (1 + 1 / sin of their angle) of the
    factors x, y [K, 3] of a predicate's normal x x y (inf where x x y = 0; ``cross``:
    x x y when the caller has it)."""
    cr = _norm(np.cross(x, y) if cross is None else cross)
    num = _norm(x) * _norm(y)
    return np.where(cr > 0, 1.0 + num / np.where(cr > 0, cr, 1), np.inf)


def cap_shapes(tri: np.ndarray, light: np.ndarray | None) -> list:
    """Screen shapes of K casters (vertices tri [K, 3, 3] in vertex-index order, as the
    edge table's rows run): [(points [K, 3, 3], ratio [K])], the front cap (normals
    A' x (B' - A') of its edges) and, with ``light`` ([3] eye-relative point light, back
    caps), the back cap (normals (L' - A') x (B' - A'))."""
    t = np.asarray(tri, np.float64)
    edges = ((0, 1), (1, 2), (0, 2))
    out = [(t, np.maximum.reduce([_pair_ratio(t[:, i], t[:, j] - t[:, i]) for i, j in edges]))]
    if light is not None:
        d = t - np.asarray(light, np.float64)
        out.append((d, np.maximum.reduce([_pair_ratio(d[:, i], d[:, j] - d[:, i])
                                          for i, j in edges])))
    return out


def _pi2_rounding(a, b, da, r_ratio, eps: float, q_bound, r=None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The eye's distance from the side planes of R sides (eye-relative a, b [R, 3],
    D_A [R, 3]; 0 where the plane is undefined) [R], and the distance [R] within which the
    edge test pi2 = (q' - A') . r may take the wrong sign for a q with |q'| <= q_bound
    (scalar or [R]): ``PAD_FACTOR`` eps |q' - A'| times r_ratio [R], the pad unit of
    r = (L' - L_w A') x (B' - A') (``_pair_ratio(-da, b - a)``: r's error is a few
    eps |L' - L_w A'| |B' - A'|; ``r`` [R, 3] when the caller has it)."""
    r = np.cross(-da, b - a) if r is None else r
    r_len = _norm(r)
    some = r_len > 0
    eye_dist = np.where(some, np.abs(np.einsum("ij,ij->i", a, r)) / np.where(some, r_len, 1.0),
                        0.0)
    return eye_dist, PAD_FACTOR * eps * r_ratio * (_norm(a) + q_bound)


def side_shapes(a: np.ndarray, b: np.ndarray, light: np.ndarray, eps: float,
                q_min: float, q_max: float) -> list:
    """Screen shape of R side quads (eye-relative edges a, b [R, 3], light [4]):
    [(points [R, 4, 3], ratio [R])] with the ratios of every predicate of the side.

    The edge test ``pi2 = (q' - A') . r`` (``r = (L' - L_w A') x (B' - A')``) bounds the
    shape only through the side plane's vanishing line: beyond it q lies on the eye's side
    of the plane, at least as far from it as the eye. It rounds by about
    eps |q' - A'| |r| (1 + ratio of r's pair), so it needs a pad (an angle of
    eps (1 + |A'| / |q'|) (1 + that ratio) from the eye) only for sides whose plane passes
    within that distance of the eye; ``eps`` is the working precision's, ``q_min`` and
    ``q_max`` bound the samples' |q'|.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    lv = np.broadcast_to(np.asarray(light[:3], np.float64), a.shape)
    lw = float(light[3])
    da, db = lw * a - lv, lw * b - lv
    r_ratio = _pair_ratio(-da, b - a)
    eye_dist, rounding = _pi2_rounding(a, b, da, r_ratio, eps, q_max)
    eye_near = eye_dist <= rounding
    pi2 = 8 * (1 + _norm(a) / max(q_min, np.finfo(np.float64).tiny)) * (1 + r_ratio)
    ratio = np.maximum.reduce([
        _pair_ratio(lv, a), _pair_ratio(lv, b), _pair_ratio(a, b - a), r_ratio,
        np.where(eye_near, pi2, 0.0)])
    return [(np.stack([a, b, da, db], axis=1), ratio)]


#: rounds of :func:`clip_fins` (each lowers a fin's depth limit to the farthest q of the
#: cells its clipped box meets); None: ZPASS fins are not clipped
FIN_CLIP_ROUNDS = 2


def clip_fins(shape: tuple, grid: "SampleGrid", basis, eps: float) -> tuple[tuple, np.ndarray]:
    """ZPASS side fins cut at the depth of the samples that can cross them.

    ZPASS counts a side's crossings between the eye and q, which lie no deeper (camera
    depth z) than q. A fin conv(A, B) + cone(D_A, D_B) (:func:`side_shapes`) is planar
    and convex; where A and B lie in front of the eye and both D_A and D_B point deeper,
    its part with z <= Z is the quad conv(A, B, A + t_A D_A, B + t_B D_B) with both new
    points at depth Z when A and B are no deeper than Z, and the triangle conv(A, C,
    A + t_A D_A) when only A is (C: the point of AB at depth Z; it then stands for B and
    D_B both). So the direction generators become points and the fin's screen region
    shrinks from the directions' vanishing points to the depth Z.

    Z starts at the farthest q of the grid's cells widened by ``DEPTH_MARGIN``; each of
    ``FIN_CLIP_ROUNDS`` rounds lowers it to the farthest q of the cells that the padded
    box of the fin cut at the current Z meets, widened likewise. By induction a sample
    whose segment E -> q crosses the fin lies in one of those cells (its crossing has
    z <= z_q <= Z), so the cut keeps every crossing.

    Rounding: the new far facet stands for the edge test pi2 (crossing before or after
    q); a q whose view ray meets the fin only beyond Z >= (1 + DEPTH_MARGIN) z_q lies at
    least ``DEPTH_MARGIN / (1 + DEPTH_MARGIN)`` of the eye's distance from the side
    plane. A fin is cut only where that exceeds pi2's rounding distance
    (:func:`_pi2_rounding`), |q'| bounded by the largest of the samples in the cells of
    the whole fin's padded box (the only ones a cut can drop); the other predicates keep
    their padded facets. Samples whose q is not in front of the eye (the 'all' cell) test
    every side anyway.

    Args:
        shape: (points [R, 4, 3] float64 (A, B, D_A, D_B), ratio [R]) of
            :func:`side_shapes`.
        grid: the samples' grid; basis: the camera basis; eps: the working precision's
            machine epsilon.
    Returns:
        ((points [R, 4, 3], ratio [R]) with the cut fins' D_A, D_B replaced by points,
        bool [R] which fins were cut).
    """
    pts, ratio = shape
    cut = np.zeros(len(pts), bool)
    real = grid.block_cell < grid.cells
    rounds = FIN_CLIP_ROUNDS
    if rounds is None or not len(pts) or not real.any() or not np.isfinite(grid.zmax[real]).all():
        return shape, cut
    a, b, da, db = (pts[:, k] for k in range(4))
    forward = -np.asarray(basis[2], np.float64)
    za, zb, dza, dzb = (pts[:, k] @ forward for k in range(4))
    able = (za > 0) & (zb > 0) & (dza > 0) & (dzb > 0)     # every generator: a bounded box
    far_table = _RangeMax(_per_cell(grid, grid.zmax[real], real))
    # the samples a cut can drop lie in the cells of the whole fin's box: their largest
    # |q'| bounds |q' - A'| (a far outlier q elsewhere on screen does not count)
    q_near = _RangeMax(_per_cell(grid, grid.q_len_max[real], real)).query(
        *_cell_box(pts[able], ratio[able], eps, basis, grid))
    a, b, da = a[able], b[able], da[able]
    eye_dist, rounding = _pi2_rounding(a, b, da, _pair_ratio(-da, b - a), eps, q_near)
    able[able] = eye_dist > (1 + 1 / DEPTH_MARGIN) * rounding
    limit = np.full(len(pts), float(grid.zmax[real].max()) * (1 + DEPTH_MARGIN))
    for step in range(rounds + 1):
        cut = able & (np.minimum(za, zb) <= limit)
        out = pts.copy()
        for end, d, z, dz, z_other in ((0, 2, za, dza, zb), (1, 3, zb, dzb, za)):
            inside = np.flatnonzero(cut & (z <= limit))       # X and X + t D_X at depth Z
            t = (limit[inside] - z[inside]) / dz[inside]
            out[inside, d] = pts[inside, end] + t[:, None] * pts[inside, d]
            beyond = np.flatnonzero(cut & (z > limit))        # both: the point of AB at Z
            other = pts[beyond, 1 - end]
            w = (limit[beyond] - z_other[beyond]) / (z[beyond] - z_other[beyond])
            point = other + w[:, None] * (pts[beyond, end] - other)
            out[beyond, end] = out[beyond, d] = point
        if step == rounds or not cut.any():
            break
        far = far_table.query(*_cell_box(out[cut], ratio[cut], eps, basis, grid))
        # a fin whose nearer end lies beyond the new limit (or whose cells hold no
        # sample: far = -inf) is crossed by no sample there; the depth cut drops it, and
        # it keeps the current limit
        new = far * (1 + DEPTH_MARGIN)
        keep = np.minimum(za[cut], zb[cut]) <= new
        limit[np.flatnonzero(cut)[keep]] = new[keep]
    return (out, ratio), cut


#: the per-cell depth cut of ZPASS sides by their planes (:func:`side_planes`); False:
#: off (the lists of the fin clip and the near-depth cut alone)
PLANE_CUT = True


#: the per-plane depth margin of the plane cut is at least this (and at least twice
#: the rounding bound's share of the eye's distance)
PLANE_MARGIN_MIN = 2.0 ** -20


def depth_planes(normal: np.ndarray, point: np.ndarray, rounding: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The planes of K primitives for the per-cell depth cut of :func:`screen_bins`.

    Each primitive lies in the plane ``normal . (x - point) = 0`` (eye-relative, [K, 3]
    each), and the kernels' predicates may misjudge on which side of it the eye or a q
    lies only within the distance ``rounding`` [K] of the plane. A sample whose view ray
    meets the plane beyond (1 + m) times its own depth lies at least ``m / (1 + m)`` of
    the eye's distance d from the plane, on the eye's side; with
    ``m = max(PLANE_MARGIN_MIN, 2 rho / (d - rho))`` (rho the rounding) that exceeds
    rho, so the predicates see the sample on the eye's side and its segment E -> q does
    not cross the primitive. A plane with ``d <= 3 rho`` (through or near the eye) is
    not usable.

    Returns:
        (normal [K, 3], offset [K]) float64: the plane ``normal . x = offset (1 + m)``
        oriented so that offset >= 0 (the eye on its negative side), the margin folded
        into the offset (the cut compares the depth ``offset / (normal . w)`` along a
        view ray w with the farthest q of a cell); offset NaN where the plane is not
        usable (the cut keeps the primitive in every cell).
    """
    normal = np.asarray(normal, np.float64)
    point = np.asarray(point, np.float64)
    offset = np.einsum("ij,ij->i", normal, point)
    length = _norm(normal)
    eye_dist = np.abs(offset) / np.where(length > 0, length, np.inf)
    usable = (eye_dist > 0) & (eye_dist > 3 * rounding)
    with np.errstate(divide="ignore", invalid="ignore"):
        margin = np.maximum(PLANE_MARGIN_MIN, 2 * rounding / (eye_dist - rounding))
    flip = np.where(offset < 0, -1.0, 1.0)
    return normal * flip[:, None], np.where(usable, np.abs(offset) / (1 + margin), np.nan)


def side_planes(a: np.ndarray, b: np.ndarray, light: np.ndarray, eps: float,
                q_max: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`depth_planes` of R side quads (eye-relative edges a, b [R, 3], light [4],
    samples with |q'| <= ``q_max``, ``eps`` the working precision's).

    The side of AB lies in the plane of ``r = (L' - L_w A') x (B' - A')`` through A'.
    The kernels see a q's side of it through the edge test pi2 (rounding distance from
    :func:`_pi2_rounding`) and the eye's side through pi3 = -D, ``D = L' . (A' x (B' -
    A'))``, whose products err by a few eps |L'| |A'| |B' - A'|: a distance of that over
    |r|, taken ``PAD_FACTOR`` times (large where the light lies close to the edge).
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    light = np.asarray(light, np.float64)
    da = float(light[3]) * a - light[:3]
    edge = b - a
    normal = np.cross(-da, edge)
    _, pi2 = _pi2_rounding(a, b, da, _pair_ratio(-da, edge, normal), eps, q_max, normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        pi3 = (PAD_FACTOR * eps * np.linalg.norm(light[:3]) * _norm(a) * _norm(edge)
               / _norm(normal))
    return depth_planes(normal, a, np.maximum(pi2, pi3))


def _cell_ranges(grid: "SampleGrid", axis: int) -> tuple[np.ndarray, np.ndarray]:
    """float64 [n]: each cell column's (axis 0) or row's (axis 1) bounds, the border
    cells cut to the samples' box (every projected q in the cell lies within)."""
    lower, upper = grid.cell_edges(axis)
    corners = grid.box_corners()[:, axis]
    return np.maximum(lower, corners.min()), np.minimum(upper, corners.max())


def _plane_depth_cut(grid: "SampleGrid", basis, ranks: np.ndarray, starts: np.ndarray,
                     lengths: np.ndarray, prim: np.ndarray, planes: tuple):
    """Drop from each cell's list the sides whose plane lies deeper than every sample
    of the cell can cross (ZPASS: a crossing lies between the eye and q).

    Along the view ray ``z w`` (``w = u right + v up + forward``, z the camera depth)
    the plane ``n . x = c`` (c >= 0) lies at depth ``c / (n . w)``; over a cell's
    rectangle it comes no nearer than Z exactly when ``c > Z max(n . w)``, and
    ``n . w`` is linear in (u, v): its maximum is its value at the centre plus
    ``|n . right| hu + |n . up| hv`` (hu, hv the half sizes). Z is the farthest q of
    the cell's blocks, and c carries the plane's margin (:func:`side_planes`): every
    sample of a cell whose side is dropped lies that margin of its depth in front of
    the plane along its ray, beyond the rounding of the kernels' test. The float64
    evaluation errs only where ``n . w`` is within a few ulps of its terms of 0, where
    the plane's depth is vastly beyond any Z unless the plane passes near the eye (then
    it is not usable). NaN (an unusable plane) keeps the side. The border cells are
    cut to the samples' box.

    Args:
        ranks, starts, lengths: the cells' lists (:func:`_cell_lists`: ranks into
            ``prim``, ascending per cell, the cells column after column).
        prim: int [K] the primitive of each rank; planes: :func:`side_planes` of the K
            primitives.
    Returns:
        (ranks, starts, lengths) of the kept entries, in the same layout.
    """
    gx, gy = grid.shape
    normal, offset = planes
    right, up, back = (np.asarray(x, np.float64) for x in basis)
    # per rank (each cell's list ascending: gathers in order): n.right, |n.right|, n.up,
    # |n.up|, n.forward, c
    a_u, a_v = normal @ right, normal @ up
    coef = [x[prim] for x in (a_u, np.abs(a_u), a_v, np.abs(a_v), -(normal @ back), offset)]
    real = grid.block_cell < grid.cells
    limit = _per_cell(grid, grid.zmax[real], real)
    (u0, u1), (v0, v1) = _cell_ranges(grid, 0), _cell_ranges(grid, 1)
    uc, hu, vc, hv = (u0 + u1) / 2, (u1 - u0) / 2, (v0 + v1) / 2, (v1 - v0) / 2
    per_cell = lengths.reshape(gy, gx)
    width = int(per_cell.sum(axis=0).max()) if len(ranks) else 0
    most, term = np.empty(width), np.empty(width)
    keep = np.empty(width, bool)
    pieces, counts = [], np.zeros((gx, gy), np.int64)
    first = 0
    # one column of cells at a time: its lists are consecutive (in cache) and u's range
    # is one; in place (no temporaries)
    for x in range(gx):
        n = int(per_cell[:, x].sum())
        if not n:
            continue
        r = ranks[first:first + n]
        m, t, k = most[:n], term[:n], keep[:n]
        np.take(coef[0], r, out=m)
        m *= uc[x]
        for col, scale in ((1, hu[x]), (2, np.repeat(vc, per_cell[:, x])),
                           (3, np.repeat(hv, per_cell[:, x]))):
            np.take(coef[col], r, out=t)
            t *= scale
            m += t
        m += coef[4][r]
        with np.errstate(invalid="ignore"):     # 0 x -inf in a cell without samples
            m *= np.repeat(limit[:, x], per_cell[:, x])
        # NaN (an unusable plane's offset, or 0 x inf) compares False: the side is kept
        np.greater(coef[5][r], m, out=k)
        np.logical_not(k, out=k)
        pieces.append(r[k])
        kept = np.zeros(n + 1, np.int64)
        np.cumsum(k.view(np.uint8), dtype=np.int64, out=kept[1:])
        counts[x] = np.diff(kept[np.cumsum(per_cell[:, x])], prepend=0)
        first += n
    kept_ranks = np.concatenate(pieces) if pieces else ranks[:0]
    return (kept_ranks, *_column_layout(counts))


def _per_cell(grid: "SampleGrid", values: np.ndarray, real: np.ndarray) -> np.ndarray:
    """[gy, gx]: the largest of the values [Nb'] of the blocks ``real`` (bool [Nb]) in
    each cell (-inf in a cell without samples)."""
    out = np.full(grid.cells, -np.inf)
    np.maximum.at(out, grid.block_cell[real], values)
    return out.reshape(grid.shape[1], grid.shape[0])


def _cell_box(pts: np.ndarray, ratio: np.ndarray, eps: float, basis, grid: "SampleGrid"):
    """(row0, row1, column0, column1) int64 [K] each: the clamped cell range of the
    padded screen boxes of K bounded primitives (generators pts [K, P, 3], all in front of
    the eye; pad as in :func:`_boxes`)."""
    u, v, _ = _project_columns(pts, basis)
    pad = _pad(ratio, np.max(u * u + v * v, axis=1), eps)
    box = _hull_box(u, v) + pad[:, None] * np.array([-1, 1, -1, 1])
    return (grid.index(box[:, 2], 1), grid.index(box[:, 3], 1),
            grid.index(box[:, 0], 0), grid.index(box[:, 1], 0))


class _RangeMax:
    """Maxima of rectangles of a 2D array [gy, gx] (a sparse table: O(1) per query)."""

    def __init__(self, values: np.ndarray):
        self.levels = {(0, 0): values}
        gy, gx = values.shape
        for i in range(gy.bit_length()):
            if i:
                below, h = self.levels[i - 1, 0], 1 << (i - 1)
                self.levels[i, 0] = np.maximum(below[:-h], below[h:])
            for j in range(1, gx.bit_length()):
                left, h = self.levels[i, j - 1], 1 << (j - 1)
                self.levels[i, j] = np.maximum(left[:, :-h], left[:, h:])

    def query(self, y0, y1, x0, x1) -> np.ndarray:
        """float [K]: the maximum over rows y0..y1 and columns x0..x1 (int [K], in range)."""
        ky = np.log2(y1 - y0 + 1).astype(np.int64)
        kx = np.log2(x1 - x0 + 1).astype(np.int64)
        out = np.full(len(y0), -np.inf)
        for i in np.unique(ky):
            for j in np.unique(kx[ky == i]):
                s = np.flatnonzero((ky == i) & (kx == j))
                t = self.levels[i, j]
                ya, yb = y0[s], y1[s] - (1 << i) + 1
                xa, xb = x0[s], x1[s] - (1 << j) + 1
                out[s] = np.maximum(np.maximum(t[ya, xa], t[ya, xb]),
                                    np.maximum(t[yb, xa], t[yb, xb]))
        return out


def _pad(ratio: np.ndarray, r2: np.ndarray, eps: float) -> np.ndarray:
    """[K]: the screen pad of K primitives whose predicates have the rounding ratios
    ``ratio`` (inf: none usable) and whose region reaches r2 = u^2 + v^2 (module
    docstring: ``PAD_FACTOR`` eps ratio, stretched by the projection, 2 (1 + r^2))."""
    unit = np.where(np.isfinite(ratio), ratio, 0.0)
    return (PAD_FACTOR * eps * unit + FACET_SLACK) * (2.0 + 2.0 * r2)


#: rows per piece of the facet cuts (:func:`_row_spans`)
ROW_PIECE = 1 << 16
#: a generator pair spans a facet plane only if |x x y| >= this times |x| |y|
FACET_CONDITION = 1e-6
#: slack (an angle, radians) of the one-side test of the other generators
FACET_SLACK = 1e-9


def cone_facets(gen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Facet half-spaces of the cones spanned by K generator sets [K, G, 3] (float64).

    Returns unit normals [K, P, 3] (P = G (G - 1) / 2, one per generator pair) and bool
    [K, P] whether that pair's plane is a facet: every generator lies on its non-negative
    side (to ``FACET_SLACK``), so the half-space ``n . d >= 0`` holds the whole cone.
    The intersection of the facets equals the cone when it is pointed and solid, and
    holds it in every case (no facet at all: the whole space).
    """
    gen = np.asarray(gen, np.float64)
    g_len = _norm(gen)
    unit = gen / np.where(g_len > 0, g_len, 1.0)[..., None]
    pairs = [(i, j) for i in range(gen.shape[1]) for j in range(i + 1, gen.shape[1])]
    normals, valid = [], []
    for i, j in pairs:
        n = np.cross(unit[:, i], unit[:, j])
        n_len = _norm(n)
        ok = n_len >= FACET_CONDITION
        n = n / np.where(ok, n_len, 1.0)[:, None]
        side = np.einsum("kd,kgd->kg", n, unit)
        pos = np.all(side >= -FACET_SLACK, axis=1)
        neg = np.all(side <= FACET_SLACK, axis=1)
        normals.append(np.where((pos | ~neg)[:, None], n, -n))
        valid.append(ok & (pos | neg))
    return np.stack(normals, axis=1), np.stack(valid, axis=1)


def _screen_lines(normals: np.ndarray, valid: np.ndarray, basis):
    """Facet half-spaces [K, P] as screen half-planes ``a u + b v + c >= 0`` with
    a^2 + b^2 = 1 (the direction of (u, v) is u right + v up - back); a facet parallel
    to the image plane is dropped (valid False)."""
    right, up, back = (np.asarray(x, np.float64) for x in basis)
    a, b, c = (normals @ right, normals @ up, -(normals @ back))
    ab = np.sqrt(a * a + b * b)
    valid = valid & (ab > FACET_CONDITION)
    ab = np.where(valid, ab, 1.0)
    return a / ab, b / ab, c / ab, valid


def _cone_lines(pts: np.ndarray, which: np.ndarray, basis):
    """:func:`_screen_lines` of the cone facets of the primitives ``which`` (bool [K])
    of pts [K, P, 3]; the others get no valid line."""
    n_pairs = pts.shape[1] * (pts.shape[1] - 1) // 2
    out = [np.zeros((len(pts), n_pairs)) for _ in range(3)]
    out.append(np.zeros((len(pts), n_pairs), bool))
    if which.any():
        for full, part in zip(out, _screen_lines(*cone_facets(pts[which]), basis)):
            full[which] = part
    return tuple(out)


def _clip_box(box: np.ndarray, lines, pad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bounding boxes [K, 4] (u0, u1, v0, v1) of K boxes cut by their padded
    half-planes ``a u + b v + c >= -pad``, and bool [K] whether anything is left.

    The corners of a convex polygon are intersections of two of its lines; those that
    satisfy every constraint (to a relative 1e-9) span the box of the polygon.
    """
    a, b, c, valid = lines
    k = len(box)
    # box edges as lines: u >= u0, -u >= -u1, v >= v0, -v >= -v1
    one, zero = np.ones((k, 1)), np.zeros((k, 1))
    la = np.concatenate([one, -one, zero, zero, np.where(valid, a, 0.0)], axis=1)
    lb = np.concatenate([zero, zero, one, -one, np.where(valid, b, 0.0)], axis=1)
    lc = np.concatenate([-box[:, :1], box[:, 1:2], -box[:, 2:3], box[:, 3:4],
                         np.where(valid, c + pad[:, None], 1.0)], axis=1)
    n = la.shape[1]
    i, j = np.triu_indices(n, 1)
    det = la[:, i] * lb[:, j] - la[:, j] * lb[:, i]
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    u = (lb[:, i] * lc[:, j] - lb[:, j] * lc[:, i]) / det
    v = (la[:, j] * lc[:, i] - la[:, i] * lc[:, j]) / det
    tol = 1e-9 * (1.0 + np.abs(u) + np.abs(v))
    inside = ok & np.all(la[:, None, :] * u[..., None] + lb[:, None, :] * v[..., None]
                         + lc[:, None, :] >= -tol[..., None], axis=2)
    any_in = inside.any(axis=1)
    big = np.inf
    out = np.stack([np.where(inside, u, big).min(1), np.where(inside, u, -big).max(1),
                    np.where(inside, v, big).min(1), np.where(inside, v, -big).max(1)], axis=1)
    return np.where(any_in[:, None], out, 0.0), any_in


def _hull_box(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """[K, 4] (u0, u1, v0, v1): the box of K projected generator sets u, v [K, P] (min and
    max elementwise over the P columns: a fraction of the time of ``u.min(1)`` for small
    P; NaN propagates alike)."""
    def across(op, x):
        return functools.reduce(op, [x[:, k] for k in range(x.shape[1])])
    return np.stack([across(np.minimum, u), across(np.maximum, u),
                     across(np.minimum, v), across(np.maximum, v)], axis=1)


def _boxes(pts: np.ndarray, ratio: np.ndarray, eps: float, basis, grid: "SampleGrid"):
    """Screen regions of K primitives with generators pts [K, P, 3]: padded boxes [K, 4]
    (u0, u1, v0, v1) cut to the padded cone, the cone's padded screen half-planes
    (a, b, c, valid [K, F] each, pad [K]), bool [K] whether the primitive is binned
    at all (False: it goes into every cell), and bool [K] whether its region misses
    the samples' box (it then enters no cell)."""
    u, v, z = _project_columns(pts, basis)
    bounded = np.all(z > 0, axis=1)
    ok = np.isfinite(ratio)
    corners = grid.box_corners()
    r2_box = float(np.max(corners[:, 0] ** 2 + corners[:, 1] ** 2))
    r2 = np.where(bounded, np.max(np.where(bounded[:, None], u * u + v * v, 0.0), axis=1),
                  r2_box)
    pad = _pad(ratio, r2, eps)
    with np.errstate(invalid="ignore"):
        hull = _hull_box(u, v)
    sample_box = np.array([corners[:, 0].min(), corners[:, 0].max(),
                           corners[:, 1].min(), corners[:, 1].max()])
    box = np.where(bounded[:, None], hull + pad[:, None] * np.array([-1, 1, -1, 1]),
                   sample_box)
    ok &= np.all(np.isfinite(box), axis=1)
    box = np.where(ok[:, None], box, 0.0)
    # facets cut the cells of a box that spans several rows and columns of cells only:
    # every row (column) of a one-column (one-row) hull box holds a point of the hull,
    # which every padded facet keeps (the module docstring; lines of the rest: invalid)
    multi = ((grid.index(box[:, 1], 0) > grid.index(box[:, 0], 0))
             & (grid.index(box[:, 3], 1) > grid.index(box[:, 2], 1)))
    lines = _cone_lines(pts, ok & (~bounded | multi), basis)
    # a bounded cone's projection is the hull of its projected generators, whose box the
    # facets cannot cut further: only an unbounded one (its box: the samples' box) is
    # cut to its cone
    cut = ok & ~bounded
    empty = np.zeros(len(box), bool)
    if cut.any():
        clipped, nonempty = _clip_box(box[cut], tuple(x[cut] for x in lines), pad[cut])
        box[cut] = np.where(nonempty[:, None], clipped, box[cut])
        empty[cut] = ~nonempty
    # no q lies outside the samples' box: a bounded box is cut to it (a primitive beside
    # every sample enters no cell, not the border cells its clamped range would reach)
    inside = np.stack([np.maximum(box[:, 0], sample_box[0]),
                       np.minimum(box[:, 1], sample_box[1]),
                       np.maximum(box[:, 2], sample_box[2]),
                       np.minimum(box[:, 3], sample_box[3])], axis=1)
    met = (inside[:, 0] <= inside[:, 1]) & (inside[:, 2] <= inside[:, 3])
    bounded_ok = ok & bounded
    box[bounded_ok] = inside[bounded_ok]
    empty |= bounded_ok & ~met
    return box, lines + (pad,), ok, empty


def screen_bins(grid: SampleGrid, shapes: list, eps: float, basis,
                near: np.ndarray | None = None, far: np.ndarray | None = None,
                planes: tuple | None = None) -> ScreenBins:
    """Bin K primitives into the cells of ``grid`` (host, float64).

    Args:
        shapes: [(points [K, P, 3], ratio [K])] from :func:`cap_shapes` or
            :func:`side_shapes`: a primitive goes into
            the cells of each of its boxes.
        eps: machine epsilon of the working precision (sets the padding).
        basis: the camera's (right, up, back) unit vectors.
        near: [K] each primitive's nearest depth, when only crossings before q count
            (the depth cut), else None.
        far: [K] each primitive's farthest depth, when only crossings beyond q count
            (the mirrored cut: a block skips the primitives nearer than its nearest q by
            more than ``DEPTH_MARGIN``), else None; not with ``near``.
        planes: with ``near``, the primitives' planes (:func:`side_planes`): each cell
            also drops the primitives whose plane lies beyond its farthest q over its
            rectangle (:func:`_plane_depth_cut`), else None.
    """
    if near is not None and far is not None:
        raise ValueError("screen_bins: a depth cut by near or by far depth, not both")
    if planes is not None and near is None:
        raise ValueError("screen_bins: the plane depth cut needs the near-depth cut")
    n_prim = len(shapes[0][0])
    n_cells = grid.cells
    boxes = [_boxes(pts, ratio, eps, basis, grid) for pts, ratio in shapes]
    # primitives in order of rank: nearest depth with a depth cut (so each cell's list
    # is in depth order), else index order
    # the cut as one rule: a block takes the primitives whose rank key is <= its limit
    if near is not None:
        rank_key = np.asarray(near, np.float64)
        limit = grid.zmax * (1 + DEPTH_MARGIN)
    elif far is not None:
        rank_key = -np.asarray(far, np.float64)
        limit = -grid.zmin * (1 - DEPTH_MARGIN)
    else:
        rank_key = limit = None
    if rank_key is None:
        prim = np.arange(n_prim)
    else:
        prim = np.argsort(rank_key, kind="stable")
    # a primitive with any box that cannot be binned goes everywhere; else the cells of
    # each box's cell range that meet its cone
    bounded = np.logical_and.reduce([ok for _, _, ok, _ in boxes])[prim]
    rank = np.flatnonzero(bounded)
    spans = []
    for box, lines, _, empty in boxes:
        keep = rank[~empty[prim[rank]]]
        row, lo, hi, which = _row_spans(grid, box, lines, prim[keep])
        spans.append((row, lo, hi, keep[which]))
    every = np.flatnonzero(~bounded)
    if len(every):                      # every row, whole, for each unbounded primitive
        gx, gy = grid.shape
        spans.append((np.tile(np.arange(gy), len(every)), np.zeros(gy * len(every), np.int64),
                      np.full(gy * len(every), gx - 1), np.repeat(every, gy)))
    ranks, starts, lengths = _cell_lists(grid, spans, unique=len(boxes) > 1)
    if planes is not None and PLANE_CUT:
        ranks, starts, lengths = _plane_depth_cut(grid, basis, ranks, starts, lengths, prim,
                                                  planes)
    # the 'all' cell: every primitive, in rank order
    ranks = np.concatenate([ranks, np.arange(n_prim, dtype=ranks.dtype)])
    starts = np.append(starts, len(ranks) - n_prim)
    lengths = np.append(lengths, n_prim)
    entries = prim.astype(np.int32)[ranks] if rank_key is not None else ranks
    bc = grid.block_cell
    if rank_key is None:
        block_len = lengths[bc]
    else:
        # entries of the block's cell within the block's depth limit: each list is in
        # rank order, and the primitives with key <= limit are the ranks below
        # searchsorted(key, limit)
        below = np.searchsorted(rank_key[prim], limit, side="right")
        block_len = _count_below(ranks, starts[bc], lengths[bc], below)
        block_len = np.where(bc == n_cells, n_prim, block_len)
    per_block = grid.block_count
    return ScreenBins(entries, starts, lengths, block_len.astype(np.int64),
                      int((~bounded).sum()), int((block_len * per_block).sum()))


def _cell_lists(grid: "SampleGrid", spans: list, unique: bool):
    """Per-cell lists of ranks from row spans: each span ``(row, lo, hi, rank)`` puts
    ``rank`` into the cells ``lo..hi`` of cell row ``row``.

    Args:
        spans: [(row, lo, hi, rank) int [M_i] each]; a single set must be in rank order.
        unique: drop a rank repeated in a cell (spans of several sets may overlap).

    Returns:
        (ranks int32 [E], starts int64 [Nc], lengths int64 [Nc]): each cell's ranks
        ascending, at ``ranks[starts[c] : starts[c] + lengths[c]]``. The lists lie
        column after column of cells (cell ids are row-major): selecting each column's
        spans keeps them in (row, rank) order, with no sort of the E entries.
    """
    gx, gy = grid.shape
    row, lo, hi, rank = (np.concatenate(x) for x in zip(*spans))
    if len(spans) > 1:                  # (row, rank) order: by rank, then stably by row
        order = stable_argsort(rank)
        by_row = order[stable_argsort(row[order])]
    else:
        by_row = stable_argsort(row)
    small = _cell_dtype(grid)
    row, lo, hi = (x[by_row].astype(small) for x in (row, lo, hi))
    rank = rank[by_row].astype(np.int32)
    pieces, counts = [], np.zeros((gx, gy), np.int64)
    for x in range(gx):
        sel = np.flatnonzero((lo <= x) & (hi >= x))
        r, y = rank[sel], row[sel]
        if unique and len(r):
            first = np.ones(len(r), bool)
            first[1:] = (y[1:] != y[:-1]) | (r[1:] != r[:-1])
            r, y = r[first], y[first]
        pieces.append(r)
        counts[x] = np.bincount(y, minlength=gy)
    ranks = np.concatenate(pieces) if pieces else np.zeros(0, np.int32)
    return (ranks, *_column_layout(counts))


def _column_layout(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) int64 [Nc] of cell lists stored column after column, from their
    lengths ``counts`` [gx, gy] (column-major); cell (row y, column x) is y * gx + x."""
    gx, gy = counts.shape
    starts = (np.cumsum(counts) - counts.ravel()).reshape(gx, gy)
    return starts.T.ravel(), counts.T.ravel()


def _count_below(values: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                 bound: np.ndarray) -> np.ndarray:
    """int64 [N]: how many of the ascending ``values[starts[i] : starts[i] + lengths[i]]``
    are below ``bound[i]`` (a binary search in each segment, all at once)."""
    lo = np.asarray(starts, np.int64).copy()
    hi = lo + lengths
    last = max(len(values) - 1, 0)
    while True:
        active = lo < hi
        if not active.any():
            return lo - starts
        mid = (lo + hi) // 2
        right = active & (values[np.minimum(mid, last)] < bound)
        lo = np.where(right, mid + 1, lo)
        hi = np.where(active & ~right, mid, hi)


def _row_spans(grid: "SampleGrid", box: np.ndarray, lines, prim: np.ndarray):
    """The cells of K primitives (indices ``prim`` [K]) that meet their cone, row by row.

    Within a cell row (v in [v0, v1]) a padded half-plane ``a u + b v + c + pad >= 0``
    holds at some point of a cell iff the cell's u range reaches the bound
    ``-(b v* + c + pad) / a`` (v* the row's end farthest along b), so each row's cells
    form one column span: the box's columns cut by every facet's bound (a cell is kept
    iff it meets each half-plane; the bounds are widened by a millionth of a cell).

    Returns the non-empty spans, in order of primitive then row: (row, lo, hi, the
    index into ``prim``) [M] each (cells lo..hi of cell row ``row``). Cell indices are
    int16 (int64 on a grid of 2^15 or more cells along an axis) and the index int32
    (int64 past 2^31 rows): a quarter and a half of the bytes of int64 rows, which the
    cuts, the gathers and :func:`_cell_lists` pass over several times.
    """
    small = _cell_dtype(grid)
    x0, x1 = (grid.index(box[prim, k], 0).astype(small) for k in (0, 1))
    y0, y1 = (grid.index(box[prim, k], 1).astype(small) for k in (2, 3))
    ny = (y1 - y0 + 1).astype(np.int64)
    n_rows = int(ny.sum())
    index = np.int32 if max(n_rows, len(prim)) < 2 ** 31 else np.int64
    row = run_offsets(ny, index).astype(small)
    row += np.repeat(y0, ny)
    lo, hi = np.repeat(x0, ny), np.repeat(x1, ny)
    ok = np.ones(len(row), bool)
    # only the rows of primitives with a facet line are cut (the others keep their box)
    cut = lines[3][prim].any(axis=1)
    rows = np.flatnonzero(np.repeat(cut, ny))
    if len(rows):
        which, cut_rows = prim[cut], ny[cut]
        # in pieces of about ROW_PIECE rows (primitives whole), so that the per-row
        # arrays of a piece stay in cache: the same values, 1.6x faster on 4 M rows
        ends = np.cumsum(cut_rows)
        splits = np.searchsorted(ends, np.arange(ROW_PIECE, ends[-1], ROW_PIECE), "right")
        for part in np.split(np.arange(len(which)), np.unique(splits)):
            if len(part):
                r = rows[ends[part[0]] - cut_rows[part[0]]:ends[part[-1]]]
                lo[r], hi[r], ok[r] = _cut_rows(grid, row[r], lo[r], hi[r],
                                                [x[which[part]] for x in lines],
                                                cut_rows[part])
    some = np.flatnonzero(ok & (hi >= lo))
    k = np.repeat(np.arange(len(prim), dtype=index), ny)
    return row[some], lo[some], hi[some], k[some]


def _cell_dtype(grid: "SampleGrid"):
    """The integer type of the grid's cell rows and columns: int16 where both fit."""
    return np.int16 if max(grid.shape) < 2 ** 15 else np.int64


def _cut_rows(grid: "SampleGrid", row, lo, hi, lines, ny):
    """The column spans ``lo..hi`` (rows ``row`` [M] of K primitives, ``ny`` [K] rows
    each, in order; cell indices of :func:`_cell_dtype`) cut by each primitive's padded
    half-planes ``lines`` (a, b, c, valid [K, F], pad [K]); returns (lo, hi, ok bool [M])
    (:func:`_row_spans`), lo and hi in the type they came in."""
    a, b, c, valid, pad = lines
    v0, v1 = (e[row] for e in grid.cell_edges(1))
    ok = np.ones(len(row), bool)
    width = 1.0 / grid.scale[0] if grid.scale[0] > 0 else 0.0
    per_row = functools.partial(np.repeat, repeats=ny)     # a primitive's value, per row
    for f in range(a.shape[1]):
        af, bf, use = a[:, f], b[:, f], valid[:, f]
        flat = use & (np.abs(af) <= FACET_CONDITION)        # no u in it: the row or none
        up = use & (af > FACET_CONDITION)                   # u >= bound
        down = use & (af < -FACET_CONDITION)                # u <= bound
        if not (flat | up | down).any():
            continue
        flat, up, down, b_row = (per_row(x) for x in (flat, up, down, bf))
        with np.errstate(invalid="ignore", divide="ignore"):
            v_end = np.where(b_row > 0, v1, np.where(b_row < 0, v0, 0.0))
            reach = b_row * v_end + per_row(c[:, f]) + per_row(pad)   # a u + reach >= 0
            bound = -reach / per_row(np.where(af != 0, af, 1.0))
        ok &= ~flat | (reach >= 0)
        with np.errstate(invalid="ignore"):
            # clamped to the grid's columns, so it fits the spans' type
            cell = grid.index(bound + np.where(up, -2e-6 * width, 2e-6 * width),
                              0).astype(lo.dtype)
        lo = np.where(up & (bound > -np.inf), np.maximum(lo, cell), lo)
        hi = np.where(down & (bound < np.inf), np.minimum(hi, cell), hi)
        ok &= ~(up & (bound == np.inf)) & ~(down & (bound == -np.inf))
    return lo, hi, ok


def farthest_depth(points: np.ndarray, basis) -> np.ndarray:
    """[K]: the largest camera depth of K point sets [K, P, 3] (eye-relative points)."""
    return _project_columns(points, basis)[2].max(axis=1)


def nearest_depth(points: np.ndarray, basis, directions: int = 0) -> np.ndarray:
    """[K]: the smallest camera depth of K point sets [K, P, 3] (eye-relative) whose
    last ``directions`` entries are directions: -inf where one of them does not point
    away from the eye plane (the primitive then reaches every depth)."""
    z = _project_columns(points, basis)[2]
    n = z.shape[1] - directions
    near = z[:, :n].min(axis=1)
    if directions:
        near = np.where(np.all(z[:, n:] > 0, axis=1), near, -np.inf)
    return near



#: lists longer than SPLIT_MIN entries (and than SPLIT_OVER_MEAN times the mean) are
#: split into parts run as separate blocks of the same samples, so one long list (e.g.
#: the back caps converging on the light's vanishing point) does not set the loop count
#: of a batch of short ones
SPLIT_MIN = 256
SPLIT_OVER_MEAN = 4.0


def batch_arrays(grid: SampleGrid, bins: ScreenBins):
    """The binned kernels' list arrays: blocks sorted by list length into batches of
    ``BATCH * BLOCK / grid.block`` (so a batch's loop count is close to each member's,
    and a batch has ``BATCH * BLOCK`` lanes at any block size), capacities bucketed to
    limit recompilation. A list longer than ``max(SPLIT_MIN, SPLIT_OVER_MEAN x mean)``
    runs as several blocks of the same samples, each on one part (the binned kernels sum
    them, ``engines.silhouette_stencil._binned_loop``).

    Returns:
        (blocks int32 [C, N] (the padding block: the last, all zeros), start int32
        [C, N], length int32 [C, N], steps int32 [C], entries int32 [E']).
    """
    # the kernels read the lists at int32 offsets
    check_int32(bucket(len(bins.entries), steps=8), "silhouette screen-cell list entries",
                "the sides and caps cover too many cells; use the option bins='off' (every "
                "sample tests every side and cap) or render fewer samples")
    length = bins.block_lengths
    first = bins.starts[grid.block_cell]
    limit = max(1, int(max(SPLIT_MIN, SPLIT_OVER_MEAN * length.mean()) if len(length)
                       else SPLIT_MIN))
    parts = np.maximum(1, -(-length // limit))
    block = np.repeat(np.arange(len(length)), parts)
    k = run_offsets(parts)
    start = np.repeat(first, parts) + k * limit
    length = np.minimum(np.repeat(length, parts) - k * limit, limit)
    per_batch = max(1, BATCH * BLOCK // grid.block)
    by_len = np.argsort(-length, kind="stable")
    n_batches = bucket(-(-len(by_len) // per_batch), minimum=1, steps=8)
    n = n_batches * per_batch
    blocks = pad(block[by_len], n, fill=len(grid.block_cell), dtype=np.int32)
    st = pad(start[by_len], n, dtype=np.int32)
    ln = pad(length[by_len], n, dtype=np.int32).reshape(n_batches, per_batch)
    entries = pad(bins.entries, bucket(len(bins.entries), steps=8), dtype=np.int32)
    return (blocks.reshape(n_batches, per_batch), st.reshape(n_batches, per_batch), ln,
            ln.max(axis=1), entries)
