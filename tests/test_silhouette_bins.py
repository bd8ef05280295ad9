"""Screen bins of the silhouette stencil: the rounding bound behind the front caps' pad,
the grid's span (outliers in border cells), and the split lists against the full
passes."""

import numpy as np
import pytest

import shadowlab as sl
import shadowlab.engines.silhouette_bins as bins
from shadowlab.core.numerics import cross3, ordered_dot
from shadowlab.engines.silhouette_bins import PAD_FACTOR
from shadowlab.scene.procedural import default_view


def _plane_trials(form, n, rng):
    """n predicates q' . (x X y) of one of the kernels' forms, in float32, with q near
    their plane: (x, y) float32 [n, 3] each as the kernel forms them, the exact plane's
    unit normal [n, 3] (float64 from the float32 inputs), the pad unit
    ``_pair_ratio`` of the exact factors [n], q float32 [n, 3] and the exact normal.

    Forms: "edge" A' x (B' - A') (the caps' and pi1's A' x B'), "light" L' x X' (sigma),
    "side" (L' - A') x (B' - A') (r: rho2 and the back caps). Vertices lie 1 to 1e4 from
    the eye, edges are 1e-6 to 0.3 of that long, the light 0.1 to 100 times as far; q
    lies at a log-uniform angle off the plane, in units of eps times the pad unit."""
    dist = 10.0 ** rng.uniform(0, 4, n)

    def point(scale):
        p = rng.normal(size=(n, 3))
        return p * (scale / np.linalg.norm(p, axis=1))[:, None]

    a = point(dist).astype(np.float32)
    b = (a + point(dist * 10.0 ** rng.uniform(-6, np.log10(0.3), n))).astype(np.float32)
    light = point(dist * 10.0 ** rng.uniform(-1, 2, n)).astype(np.float32)
    a64, b64, l64 = (v.astype(np.float64) for v in (a, b, light))
    if form == "edge":
        x, y, exact = a, b - a, (a64, b64 - a64)
    elif form == "light":
        x, y, exact = light, a, (l64, a64)
    else:
        x, y, exact = light - a, b - a, (l64 - a64, b64 - a64)
    normal = np.cross(*exact)
    keep = np.linalg.norm(normal, axis=1) > 0
    unit_n = normal / np.where(keep, np.linalg.norm(normal, axis=1), 1.0)[:, None]
    ratio = bins._pair_ratio(*exact)
    w = rng.uniform(-0.5, 1.5, n)[:, None]
    along = (1 - w) * exact[0] + w * exact[1]
    along /= np.linalg.norm(along, axis=1)[:, None]
    eps = np.finfo(np.float32).eps
    units = 10.0 ** rng.uniform(-3, 1, n) * rng.choice([-1.0, 1.0], n)
    theta = np.clip(units * eps * ratio, -1.0, 1.0)
    depth = dist * rng.uniform(0.5, 2.0, n)
    q = (np.cos(theta)[:, None] * along + np.sin(theta)[:, None] * unit_n) * depth[:, None]
    return (x[keep], y[keep], unit_n[keep], ratio[keep],
            q[keep].astype(np.float32), normal[keep])


@pytest.mark.parametrize("form", ["edge", "light", "side"])
def test_plane_predicate_rounding_within_the_pad(form):
    """Each plane predicate of the kernels, evaluated in float32 as they do (the factors
    formed as they form them, ordered unfused products), takes the wrong sign only for
    q within a small part of the pad's angle (PAD_FACTOR eps ratio 2 (1 + r^2), ratio
    = 1 + |x| |y| / |x x y| of the exact factors) of its plane."""
    rng = np.random.default_rng(11)
    eps = float(np.finfo(np.float32).eps)
    worst, wrong_total = 0.0, 0
    cols = [lambda v, k=k: v[:, k] for k in range(3)]
    for _ in range(4):
        x, y, unit_n, ratio, q32, normal = _plane_trials(form, 250_000, rng)
        c = cross3([f(x) for f in cols], [f(y) for f in cols], np.multiply)
        got = ordered_dot([f(q32) for f in cols], c, np.multiply)
        assert got.dtype == np.float32
        q64 = q32.astype(np.float64)
        exact = np.einsum("kd,kd->k", q64, normal)
        # the angle of the rounded q (as the kernel sees it) off the exact plane
        angle = np.abs(np.einsum("kd,kd->k", q64, unit_n)) / np.linalg.norm(q64, axis=1)
        # float64's own error is ~1e-9 of float32's: exact signs away from zero
        clear = angle > 1e-12 * ratio
        wrong = clear & (np.sign(got) != np.sign(exact))
        wrong_total += int(np.count_nonzero(wrong))
        if wrong.any():
            worst = max(worst, float(np.max(angle[wrong] / (eps * ratio[wrong]))))
    # the trials reach into the rounding zone (the check can fail) ...
    assert wrong_total > 100
    # ... and every wrong sign lies well inside the pad's angle (2 PAD_FACTOR units)
    assert worst < PAD_FACTOR / 4, worst


@pytest.mark.parametrize("kind", ["normal", "ties", "sorted", "outliers", "constant"])
def test_tail_quantiles_are_numpys_quantiles_bit_for_bit(kind):
    """The candidates-by-threshold quantiles against np.quantile itself, on sizes on
    both sides of the subsample path and inputs that bias a strided subsample."""
    rng = np.random.default_rng(len(kind))
    for n in (1, 7, 4 * bins.TAIL_SUBSAMPLE - 1, 4 * bins.TAIL_SUBSAMPLE, 50_001, 300_000):
        if kind == "normal":
            x = rng.normal(size=n)
        elif kind == "ties":
            x = rng.integers(0, 40, n).astype(np.float64)
        elif kind == "sorted":                  # every strided sample from one end
            x = np.sort(rng.uniform(-1, 1, n))[::-1].copy()
        elif kind == "outliers":                # a few far values, as grazing q
            x = rng.uniform(size=n)
            x[rng.integers(0, n, 5)] = rng.normal(scale=1e6, size=5)
        else:
            x = np.full(n, 0.25)
        for q in (0.0, 1e-3, 0.01, 0.3, 0.5):
            want = np.quantile(x, [q, 1 - q])
            assert bins.tail_quantiles(x, q) == (want[0], want[1]), (kind, n, q)


def test_the_grid_spans_the_core_of_q_and_an_outlier_lands_in_a_border_cell():
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.5, 0.5, 100_000)
    assert bins.core_range(x) == (x.min(), x.max())         # no outlier: the whole box
    lo, hi = bins.core_range(np.append(x, 60.0))             # a grazing sample's far q
    assert -0.5 <= lo < -0.49 and 0.49 < hi < 0.56
    basis = np.eye(3)
    q = np.stack([np.append(x, 60.0), np.append(x[::-1], 0.0), -np.ones(len(x) + 1)], 1)
    grid = bins.sample_grid(q, basis, (512, 512))
    assert 1.0 / grid.scale[0] < 0.04                         # 32 cells over ~1 unit, not 60
    assert grid.cell[-1] % grid.shape[0] == grid.shape[0] - 1  # the last column
    assert grid.box_corners()[:, 0].max() >= 60.0             # all q still in the box


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("behind", [0, 7])
def test_sample_grid_layout_against_a_plain_loop(dtype, behind):
    """Every sample sits in its cell's blocks, in order of its depth key within the cell
    (ties in sample order); each block's depth range, its cell and its q rows match a
    per-sample loop; samples behind the eye (``behind`` of them) go to the extra cell,
    depth inf."""
    rng = np.random.default_rng(5)
    s = 3000
    depth = np.where(rng.random(s) < 0.5, rng.choice([1.0, 2.0, 3.0], s),   # ties
                     rng.uniform(1.0, 3.0, s) * (1 + 1e-7 * rng.random(s)))
    q = np.stack([rng.uniform(-1, 1, s), rng.uniform(-1, 1, s), -depth], 1)
    q[rng.choice(s, behind, replace=False), 2] *= -1.0
    q = q.astype(dtype)
    basis = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))
    grid = bins.sample_grid(q, basis, (64, 48), tile=16, block=8)
    q64 = q.astype(np.float64)
    z = -q64[:, 2]
    good = z > 0
    assert np.array_equal(grid.cell == grid.cells, ~good)
    for i in np.flatnonzero(good)[:200]:                  # the clamped cell of (u, v)
        col, row = (min(max(int(np.floor((q64[i, k] / z[i] - grid.lo[k]) * grid.scale[k])),
                            0), grid.shape[k] - 1) for k in (0, 1))
        assert grid.cell[i] == row * grid.shape[0] + col
    key = bins._depth_key(z, good)
    for c in np.unique(grid.cell):
        members = np.flatnonzero(grid.cell == c)
        want = members[np.lexsort((members, key[members]))]     # by key, ties by index
        slots = grid.slot[want]
        first = slots[0] // grid.block
        assert np.array_equal(slots, first * grid.block + np.arange(len(want)))
        for b in range(first, first + -(-len(want) // grid.block)):
            inside = want[(slots // grid.block) == b]
            assert grid.block_cell[b] == c
            assert grid.zmax[b] == (z[inside].max() if good[inside].all() else np.inf)
            assert grid.zmin[b] == (z[inside].min() if good[inside].all() else -np.inf)
            assert grid.q_len_max[b] == np.linalg.norm(q64[inside], axis=1).max()
            assert grid.block_count[b] == len(inside)
            np.testing.assert_array_equal(grid.q[b][: len(inside)], q[inside])
            assert not grid.q[b][len(inside):].any()
    assert not grid.q[-1].any() and grid.q.dtype == dtype
    lengths = np.linalg.norm(q64, axis=1)
    assert grid.q_len_range == (lengths.min(), lengths.max())
    empty = bins.sample_grid(q[:0], basis, (64, 48), tile=16, block=8)
    assert empty.q.shape == (1, 8, 3) and len(empty.zmax) == len(empty.slot) == 0


def test_depth_key_is_monotone_in_depth():
    """The 16-bit depth key never orders a nearer sample after a farther one, spans the
    whole range, and gives the samples that are not in front of the eye the last key."""
    rng = np.random.default_rng(8)
    z = np.concatenate([10.0 ** rng.uniform(-3, 5, 5000), [0.0, -2.0, np.inf]])
    good = np.isfinite(z) & (z > 0)
    key = bins._depth_key(z, good)
    order = np.argsort(z[good])
    assert np.all(np.diff(key[good][order].astype(np.int64)) >= 0)
    assert key[good].min() == 0 and key[good].max() == 65535
    assert np.all(key[~good] == 65535)
    assert np.all(bins._depth_key(np.full(4, 2.0), np.ones(4, bool)) == 0)


def _unbinned_small_grid(stencil, precision):
    """2 x 2 spheres of 200 triangles at 32x32 and their unbinned silhouette result:
    (scene, gbuf, light, result)."""
    params = {"n": 2, "triangles_per_sphere": 200}
    scene = sl.load_scene("sphere_grid", **params)
    view = default_view("sphere_grid", scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(32, 32)))
    full = sl.compute_shadows(scene, gbuf, view.light, method="silhouette", bins="off",
                              stencil=stencil, precision=precision)
    return scene, gbuf, view.light, full


def _assert_same_counts(full, binned):
    """Equal per-pixel stencil updates and cap crossings, and an equal lit mask."""
    for key in ("stencil_updates_per_pixel", "cap_crossings_per_pixel"):
        if key in full.counters:
            assert np.array_equal(np.asarray(full.counters[key]),
                                  np.asarray(binned.counters[key])), key
    assert np.array_equal(full.lit, binned.lit)


@pytest.mark.parametrize("stencil", ["zpass", "zfail"])
def test_border_cells_hold_every_q_outside_the_grid(monkeypatch, stencil, precision):
    """A grid spanning only the central 60 % of the q (the rest in its border cells,
    which reach infinity) gives the unbinned passes' per-pixel counts and lit mask."""
    scene, gbuf, light, full = _unbinned_small_grid(stencil, precision)
    monkeypatch.setattr(bins, "CORE_QUANTILE", 0.2)
    monkeypatch.setattr(bins, "CORE_MARGIN", 0.0)
    narrow = sl.compute_shadows(scene, gbuf, light, method="silhouette",
                                bins="screen", stencil=stencil, precision=precision)
    _assert_same_counts(full, narrow)


@pytest.mark.parametrize("stencil", ["zpass", "zfail"])
def test_split_lists_equal_the_full_passes(monkeypatch, stencil, precision):
    """With every list split into parts of at most 4 entries (each part its own block
    of the same samples), the binned passes still give the full passes' per-pixel
    counts and lit mask."""
    scene, gbuf, light, full = _unbinned_small_grid(stencil, precision)
    calls = []
    real = bins.batch_arrays

    def spy(grid, b):
        out = real(grid, b)
        calls.append((len(grid.block_cell), int(np.count_nonzero(out[2]))))
        return out

    monkeypatch.setattr(bins, "SPLIT_MIN", 4)
    monkeypatch.setattr(bins, "SPLIT_OVER_MEAN", 0.0)
    monkeypatch.setattr("shadowlab.methods.silhouette.batch_arrays", spy)
    split = sl.compute_shadows(scene, gbuf, light, method="silhouette", bins="screen",
                               stencil=stencil, precision=precision)
    # some list was split (more non-empty parts than blocks)
    assert any(parts > blocks for blocks, parts in calls), calls
    _assert_same_counts(full, split)


class _Grid:
    """The part of a SampleGrid that the list builder reads."""

    def __init__(self, gx, gy):
        self.shape = (gx, gy)


@pytest.mark.parametrize("sets,unique", [(1, False), (2, True), (3, True)])
def test_cell_lists_equal_a_plain_loop_over_the_spans(sets, unique):
    """Each cell's list from row spans (one set in rank order, or several overlapping
    sets with repeats dropped) equals a plain loop over the spans, ranks ascending."""
    rng = np.random.default_rng(5 + sets)
    gx, gy, n_rank = 7, 5, 60
    spans = []
    for s in range(sets):
        m = 200
        if sets == 1:       # one set: in rank order, a rank's rows distinct
            rank, row = np.divmod(np.sort(rng.choice(n_rank * gy, m, replace=False)), gy)
        else:
            rank, row = rng.integers(0, n_rank, m), rng.integers(0, gy, m)
        lo = rng.integers(0, gx, m)
        hi = np.minimum(gx - 1, lo + rng.integers(0, 4, m))
        spans.append((row, lo, hi, rank))
    ranks, starts, lengths = bins._cell_lists(_Grid(gx, gy), spans, unique=unique)
    expect = {c: [] for c in range(gx * gy)}
    for row, lo, hi, rank in spans:
        for y, a, b, r in zip(row, lo, hi, rank):
            for x in range(a, b + 1):
                expect[y * gx + x].append(int(r))
    for c in range(gx * gy):
        want = sorted(set(expect[c])) if unique else sorted(expect[c])
        got = ranks[starts[c]: starts[c] + lengths[c]].tolist()
        assert got == want, c
    assert lengths.sum() == len(ranks)


def test_count_below_equals_a_search_per_segment():
    """The all-at-once binary search counts, in each ascending segment, the values below
    the bound, as np.searchsorted does segment by segment (empty segments included)."""
    rng = np.random.default_rng(9)
    lengths = rng.integers(0, 40, 300)
    values = np.concatenate([np.sort(rng.integers(0, 100, n)) for n in lengths]).astype(np.int32)
    starts = np.cumsum(lengths) - lengths
    bound = rng.integers(-5, 110, 300)
    got = bins._count_below(values, starts, lengths, bound)
    want = [np.searchsorted(values[s: s + n], b) for s, n, b in zip(starts, lengths, bound)]
    np.testing.assert_array_equal(got, want)


def test_lists_int32_offsets_cannot_address_are_refused(monkeypatch):
    """The binned kernels read the cell lists at int32 offsets: lists longer than that
    are refused with an error naming them and the way out (bins='off'), never wrapped.
    The limit is lowered here to a few hundred entries; bins='off' still runs."""
    from shadowlab.core import capacity
    scene, gbuf, light, full = _unbinned_small_grid("zpass", "float32")
    monkeypatch.setattr(capacity, "INT32_MAX", 300)
    with pytest.raises(capacity.CapacityError, match="cell list entries.*bins='off'"):
        sl.compute_shadows(scene, gbuf, light, method="silhouette", bins="screen",
                           stencil="zpass", precision="float32")
    again = sl.compute_shadows(scene, gbuf, light, method="silhouette", bins="off",
                               stencil="zpass", precision="float32")
    assert np.array_equal(again.lit, full.lit)


def test_range_max_equals_a_plain_loop():
    """The sparse table's rectangle maxima equal a loop over the rectangle's cells."""
    rng = np.random.default_rng(3)
    for gy, gx in ((1, 1), (5, 9), (16, 16), (33, 7)):
        values = rng.normal(size=(gy, gx))
        values[rng.random((gy, gx)) < 0.2] = -np.inf
        y0, y1 = np.sort(rng.integers(0, gy, (2, 200)), axis=0)
        x0, x1 = np.sort(rng.integers(0, gx, (2, 200)), axis=0)
        got = bins._RangeMax(values).query(y0, y1, x0, x1)
        want = [values[a:b + 1, c:d + 1].max() for a, b, c, d in zip(y0, y1, x0, x1)]
        np.testing.assert_array_equal(got, want)


class _FlatGrid:
    """A sample grid whose cells all reach the same depth (what clip_fins reads)."""

    def __init__(self, depth, box=2.0):
        self.shape, self.cells = (8, 8), 64
        self.lo, self.scale = (-box, -box), (8 / (2 * box), 8 / (2 * box))
        self.block_cell = np.arange(64)
        self.zmax = np.full(64, depth)
        self.q_len_max = np.full(64, depth)

    def index(self, x, axis):
        return bins.SampleGrid.index(self, x, axis)


@pytest.mark.parametrize("directional", [False, True])
def test_clipped_fins_hold_every_point_of_the_fin_before_the_limit(directional):
    """Every point of a fin no deeper than the limit lies in the cone of the clipped
    generators (their facet half-spaces), and the clipped generators lie on the fin at
    most at the limit's depth; a fin whose directions do not both point deeper is kept."""
    rng = np.random.default_rng(7)
    basis = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))  # z = -w
    n = 400
    a = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), -rng.uniform(2, 6, n)], 1)
    b = a + rng.normal(scale=0.5, size=(n, 3))
    light = (np.array([0.3, 1.0, 0.4, 0.0]) if directional
             else np.array([*rng.normal(size=3) * 3 + [0, 4, -4], 1.0]))
    shape = bins.side_shapes(a, b, light, np.finfo(np.float32).eps, 1.0, 10.0)[0]
    depth = 6.0
    (pts, _), cut = bins.clip_fins(shape, _FlatGrid(depth), basis, np.finfo(np.float32).eps)
    z = -pts[..., 2]
    dives = (-shape[0][:, 2, 2] > 0) & (-shape[0][:, 3, 2] > 0)
    assert cut.any() and not (cut & ~dives).any()
    np.testing.assert_array_equal(pts[~cut], shape[0][~cut])
    limit = depth * (1 + bins.DEPTH_MARGIN)
    assert np.all(z[cut] <= limit * (1 + 1e-12))
    normals, valid = bins.cone_facets(pts[cut])
    da, db = shape[0][cut, 2], shape[0][cut, 3]
    hits = 0
    for s_, t_ in rng.uniform(0, 1, (60, 2)):
        t_ = 30 * t_ ** 3
        x = (1 - s_) * (a[cut] + t_ * da) + s_ * (b[cut] + t_ * db)
        before = -x[:, 2] <= limit
        side = np.einsum("kpd,kd->kp", normals, x / np.linalg.norm(x, axis=1)[:, None])
        inside = np.all(~valid | (side >= -1e-9), axis=1)
        assert inside[before].all()
        hits += int(before.sum())
    assert hits > 1000


def test_clipped_fins_test_fewer_sides_for_the_same_counts(monkeypatch, precision):
    """ZPASS with the fins clipped at their samples' depth gives the unbinned passes'
    per-pixel counts and lit mask with fewer side tests than unclipped bins."""
    scene, gbuf, light, full = _unbinned_small_grid("zpass", precision)
    clipped = sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision)
    monkeypatch.setattr(bins, "FIN_CLIP_ROUNDS", None)
    whole = sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision)
    _assert_same_counts(full, clipped)
    _assert_same_counts(full, whole)
    assert clipped.counters["clipped_sides"] > 0 == whole.counters["clipped_sides"]
    assert clipped.counters["side_tests"] < whole.counters["side_tests"]


@pytest.mark.parametrize("stencil", ["zpass", "zfail"])
def test_facet_cuts_in_small_pieces_equal_the_full_passes(monkeypatch, stencil, precision):
    """The facet cuts run on pieces of 3 rows (primitives whole) give the unbinned
    passes' per-pixel counts and lit mask, and the side and cap tests of one piece."""
    scene, gbuf, light, full = _unbinned_small_grid(stencil, precision)
    kwargs = dict(method="silhouette", bins="screen", stencil=stencil, precision=precision)
    whole = sl.compute_shadows(scene, gbuf, light, **kwargs)
    monkeypatch.setattr(bins, "ROW_PIECE", 3)
    calls = []
    real = bins._cut_rows

    def spy(grid, row, *rest):
        calls.append(len(row))
        return real(grid, row, *rest)

    monkeypatch.setattr(bins, "_cut_rows", spy)
    pieces = sl.compute_shadows(scene, gbuf, light, **kwargs)
    assert len(calls) > 2 and max(calls) < 3 + max(gbuf.valid.shape)     # pieces were cut
    _assert_same_counts(full, pieces)
    for key in ("side_tests", "cap_tests"):
        assert pieces.counters[key] == whole.counters[key], key


@pytest.mark.parametrize("stencil", ["zpass", "zfail"])
def test_row_spans_in_narrow_and_wide_integers_agree(monkeypatch, stencil, precision):
    """The spans' int16 cells and int32 indices (grids under 2^15 cells a side) give the
    unbinned passes' counts and the same side and cap tests as int64 ones (the type of
    larger grids)."""
    scene, gbuf, light, full = _unbinned_small_grid(stencil, precision)
    kwargs = dict(method="silhouette", bins="screen", stencil=stencil, precision=precision)
    types = []
    real = bins._row_spans

    def spy(*args):
        out = real(*args)
        types.append(tuple(x.dtype for x in out))
        return out

    monkeypatch.setattr(bins, "_row_spans", spy)
    narrow = sl.compute_shadows(scene, gbuf, light, **kwargs)
    assert types and set(types) == {tuple(map(np.dtype, ('int16',) * 3 + ('int32',)))}
    monkeypatch.setattr(bins, "_cell_dtype", lambda grid: np.int64)
    types.clear()
    wide = sl.compute_shadows(scene, gbuf, light, **kwargs)
    assert types and set(types) == {tuple(map(np.dtype, ('int64',) * 3 + ('int32',)))}
    _assert_same_counts(full, narrow)
    _assert_same_counts(full, wide)
    for key in ("side_tests", "cap_tests"):
        assert narrow.counters[key] == wide.counters[key], key


def test_plane_depth_cut_keeps_every_side_a_sample_can_cross():
    """The per-cell plane depth cut equals a plain loop over each cell rectangle's four
    corners (a plane is kept iff it reaches a depth of at most the cell's limit in
    front of the eye somewhere over the rectangle, or is not usable), and keeps every
    plane that some sample of the cell has in front of it along its view ray."""
    rng = np.random.default_rng(11)
    s, k = 2500, 60
    basis = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))
    depth = rng.uniform(2.0, 6.0, s)
    q = np.stack([rng.uniform(-1, 1, s) * depth, rng.uniform(-0.7, 0.7, s) * depth, -depth], 1)
    grid = bins.sample_grid(q, basis, (64, 48), tile=16, block=8)
    gx, gy = grid.shape
    # planes through points 1 to 8 deep, c >= 0 (the eye on the negative side)
    normal = rng.normal(size=(k, 3))
    point = np.stack([rng.uniform(-2, 2, k), rng.uniform(-2, 2, k), -rng.uniform(1, 8, k)], 1)
    offset = np.einsum("ij,ij->i", normal, point)
    normal *= np.where(offset < 0, -1.0, 1.0)[:, None]
    offset = np.abs(offset)
    offset[rng.random(k) < 0.1] = np.nan                     # not usable: kept everywhere
    prim = rng.permutation(k)
    # every rank in every cell, cells column after column
    lengths = np.full(grid.cells, k)
    layout = np.arange(grid.cells).reshape(gy, gx).T.ravel()
    starts = np.empty(grid.cells, np.int64)
    starts[layout] = np.arange(grid.cells) * k
    ranks = np.tile(np.arange(k, dtype=np.int32), grid.cells)
    got_ranks, got_starts, got_lengths = bins._plane_depth_cut(
        grid, basis, ranks, starts, lengths, prim, (normal, offset))
    # the samples' projected positions and each cell's farthest depth
    u, v, z = q[:, 0] / depth, q[:, 1] / depth, depth
    limit = np.full(grid.cells, -np.inf)
    np.maximum.at(limit, grid.cell, z)
    kept_pairs = 0
    for c in range(grid.cells):
        got = set(prim[got_ranks[got_starts[c]:got_starts[c] + got_lengths[c]]])
        x, y = c % gx, c // gx
        inside = grid.cell == c
        us = [grid.lo[0] + (x + e) / grid.scale[0] for e in (0, 1)]
        vs = [grid.lo[1] + (y + e) / grid.scale[1] for e in (0, 1)]
        if x == 0:
            us[0] = u.min()
        if x == gx - 1:
            us[1] = u.max()
        if y == 0:
            vs[0] = v.min()
        if y == gy - 1:
            vs[1] = v.max()
        for p in range(k):
            reach = max(normal[p] @ np.array([uu, vv, -1.0]) for uu in us for vv in vs)
            want = np.isnan(offset[p]) or offset[p] <= limit[c] * reach
            assert (p in got) == want, (c, p)
            kept_pairs += want
            # a sample of the cell that has the plane between itself and the eye
            s_dot = (normal[p] @ np.stack([u[inside], v[inside], -np.ones(inside.sum())]))
            with np.errstate(divide="ignore"):
                z_plane = offset[p] / s_dot
            if np.any((s_dot > 0) & (z_plane <= z[inside])):
                assert p in got, (c, p)
        assert list(got_ranks[got_starts[c]:got_starts[c] + got_lengths[c]]) == sorted(
            np.flatnonzero(np.isin(prim, list(got))))
    assert 0 < kept_pairs < grid.cells * k                  # the cut drops some, keeps some


def test_plane_depth_cut_tests_fewer_sides_for_the_same_counts(monkeypatch, precision):
    """ZPASS with the per-cell plane depth cut gives the unbinned passes' per-pixel
    counts and lit mask with fewer side tests than without it."""
    scene = sl.load_scene("fuzzy", triangles=2000)
    view = default_view("fuzzy", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(40, 40)))
    kwargs = dict(method="silhouette", precision=precision)
    full = sl.compute_shadows(scene, gbuf, view.light, bins="off", **kwargs)
    cut = sl.compute_shadows(scene, gbuf, view.light, **kwargs)
    monkeypatch.setattr(bins, "PLANE_CUT", False)
    whole = sl.compute_shadows(scene, gbuf, view.light, **kwargs)
    _assert_same_counts(full, cut)
    _assert_same_counts(full, whole)
    assert cut.counters["side_tests"] < whole.counters["side_tests"]


def test_side_plane_margins_keep_the_kernels_crossings():
    """A sample whose view ray meets a side's plane beyond (1 + m) times its depth (m the
    margin folded into :func:`side_planes`' offset) is not counted as crossing the side
    by the kernels' own float32 test; the same samples moved beyond the plane are, for
    most sides (the check can fail). Edges 1 to 1e4 from the eye, 1e-5 to 0.3 of that
    long, under a point light 50 away or a directional light; and edges 1e-3 to 3 from
    a point light 30 away (pi3's rounding grows as the light nears the edge)."""
    import jax.numpy as jnp

    from shadowlab.core.numerics import opaque_multiplier, opaque_zero
    from shadowlab.engines.silhouette_stencil import _side_crossing, edge_table, vertex_terms

    rng = np.random.default_rng(3)
    n = 20_000
    eps = float(np.finfo(np.float32).eps)

    def point(scale):
        p = rng.normal(size=(n, 3))
        return p * (scale / np.linalg.norm(p, axis=1))[:, None]

    def far_edges():
        dist = 10.0 ** rng.uniform(0, 4, n)
        a = point(dist)
        a[:, 2] = -np.abs(a[:, 2])                          # in front of the eye (z < 0)
        return a, a + point(dist * 10.0 ** rng.uniform(-5, np.log10(0.3), n)), dist

    def near_light_edges(light):
        a = light[:3] + point(10.0 ** rng.uniform(-3, 0.5, n))
        b = a + point(np.linalg.norm(a - light[:3], axis=1) * 10.0 ** rng.uniform(-2, 0, n))
        return a, b, np.linalg.norm(a, axis=1)

    near = np.array([1.0, -2.0, -30.0, 1.0])
    cases = [(np.append(point(1.0)[0] * 50.0, 1.0), far_edges()),
             (np.append(point(1.0)[0], 0.0), far_edges()),
             (near, near_light_edges(near))]
    for light, (a, b, dist) in cases:
        a, b, light = a.astype(np.float32), b.astype(np.float32), light.astype(np.float32)
        a64, b64, l64 = a.astype(np.float64), b.astype(np.float64), light.astype(np.float64)
        da = l64[3] * a64 - l64[:3]
        normal, offset = bins.side_planes(a64, b64, l64, eps, 2 * dist.max())
        use = np.isfinite(offset)
        # a point X of each fin (between the ends, beyond the edge from the light)
        s, t = rng.uniform(0.05, 0.95, n), 10.0 ** rng.uniform(-3, 0.5, n)
        x = a64 + s[:, None] * (b64 - a64) + (t * dist / np.linalg.norm(da, axis=1))[:, None] * da
        c_full = np.einsum("ij,ij->i", normal, a64)          # the plane's own offset
        margin = c_full / offset - 1.0
        front = x[:, 2] < 0
        verts = jnp.asarray(np.concatenate([a, b]))
        terms = vertex_terms(verts, jnp.asarray(light))
        table = edge_table(jnp.asarray(a), jnp.asarray(b), terms[:n], terms[n:],
                           jnp.asarray(light))
        mul = opaque_multiplier(opaque_zero(jnp.asarray(light)))
        row = [table[:, k] for k in range(16)]
        counted = {}
        for name, scale in (("before", 1 / (1 + margin) * (1 - 4 * eps)),
                            ("beyond", 1 + np.maximum(margin, 1e-3))):
            q = (x * np.where(use, scale, 1.0)[:, None]).astype(np.float32)
            q64 = q.astype(np.float64)
            # the plane's depth along q's own (rounded) ray, over q's depth
            ratio = offset * (1 + margin) / np.einsum("ij,ij->i", normal, q64)
            ok = use & front & np.isfinite(ratio)
            if name == "before":
                ok &= ratio >= 1 + margin
            ds, _ = _side_crossing([jnp.asarray(q[:, k]) for k in range(3)], row,
                                   jnp.int32(1), jnp.int32(1), False, mul)
            counted[name] = (np.asarray(ds) != 0) & ok
            if name == "before":
                assert ok.sum() > n // 3
        assert not counted["before"].any()
        assert counted["beyond"].sum() > n // 3


def test_plane_depth_cut_keeps_an_outlier_of_a_collapsed_grid():
    """When nearly every q shares one u (the grid's core has no width, so every q lies
    in the first column), a plane between the eye and an outlier q off that line stays
    in the outlier's cell."""
    basis = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))  # z = -w
    rng = np.random.default_rng(2)
    q = np.stack([np.zeros(2001), rng.uniform(-0.5, 0.5, 2001), -np.ones(2001)], 1)
    q[-1] = (0.5, 0.0, -1.0)                        # the outlier
    grid = bins.sample_grid(q, basis, (64, 64), tile=16, block=8)
    assert grid.scale[0] == 0 and grid.cell[-1] == grid.cell[0] // grid.shape[0] * grid.shape[0]
    # the plane x = 0.3 crosses the outlier's segment E -> q at 0.6 of its depth
    normal, offset = np.array([[1.0, 0.0, 0.0]]), np.array([0.3])
    gx, gy = grid.shape
    layout = np.arange(grid.cells).reshape(gy, gx).T.ravel()
    lengths = np.ones(grid.cells, np.int64)
    starts = np.empty(grid.cells, np.int64)
    starts[layout] = np.arange(grid.cells)
    ranks = np.zeros(grid.cells, np.int32)
    _, _, kept = bins._plane_depth_cut(grid, basis, ranks, starts, lengths, np.array([0]),
                                       (normal, offset))
    assert kept[grid.cell[-1]] == 1


def test_screen_bins_refuse_planes_without_the_near_cut():
    """The plane depth cut only holds for crossings before q: planes without the
    near-depth cut are refused with a message naming both."""
    basis = (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))
    q = np.stack([np.linspace(-1, 1, 50), np.linspace(-1, 1, 50), -np.ones(50)], 1)
    grid = bins.sample_grid(q, basis, (16, 16), tile=8, block=8)
    shapes = [(np.array([[[0.0, 0, -2], [0.1, 0, -2], [0, 0.1, -2]]]), np.array([2.0]))]
    planes = (np.array([[0.0, 0.0, -1.0]]), np.array([2.0]))
    with pytest.raises(ValueError, match="plane depth cut needs the near-depth cut"):
        bins.screen_bins(grid, shapes, 1e-7, basis, planes=planes)
