"""PSV queries: equal to the reference, overflow detection, counters against plain loops."""

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.core import timing
from shadowlab.core.capacity import CapacityError
from shadowlab.methods import psv as psvm
from shadowlab.structures import top_tree as tt
from shadowlab.core.frame import precision_mode, view_samples
from shadowlab.scene import caches
from shadowlab.scene.procedural import default_view

METHODS = ("psv", "d_psv", "d_stackless", "d_hybrid")
SCENES = {
    "gate": {"trees": 4, "leaves_per_tree": 80, "bars": 5},
    "sphere_grid": {"n": 3, "triangles_per_sphere": 200},
    "soup": {"count": 100},
    "fuzzy": {"triangles": 3000},
}


def _setup(name, res=64):
    params = SCENES[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    return scene, view.light, gbuf, sl.reference_shadows(scene, gbuf, view.light)


_CACHE = {}


def _scene(name, res=64):
    if (name, res) not in _CACHE:
        _CACHE[(name, res)] = _setup(name, res)
    return _CACHE[(name, res)]


@pytest.mark.parametrize("name", list(SCENES))
def test_queries_equal_reference(name, precision):
    scene, light, gbuf, truth = _scene(name)
    visited = {}
    for m in METHODS:
        r = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision)
        ok = gbuf.valid
        if m in ("psv", "d_psv"):
            ok = ok & (r.counters["stack_overflows_per_pixel"] == 0)
        assert np.count_nonzero((r.lit != truth) & ok) == 0, m
        visited[m] = r.counters["visited_nodes"]
        assert r.counters["visited_nodes"] == r.counters["visited_nodes_per_pixel"].sum()
    # The depth test never adds visits to the stack query; hybrid with a stack that
    # never fills visits exactly what D-PSV visits.
    assert visited["d_psv"] <= visited["psv"]


def test_options_keep_the_result():
    scene, light, gbuf, truth = _scene("gate")
    for opts in ({"wedge": "off"}, {"wedge": "signed"}, {"order": "mesh"},
                 {"order": "distance"},
                 {"frustum_culling": True}, {"seed": 5}, {"build": "sequential"}):
        r = sl.compute_shadows(scene, gbuf, light, method="d_hybrid", **opts)
        assert np.count_nonzero((r.lit != truth) & gbuf.valid) == 0, opts


def _same(a, b):
    assert np.array_equal(a.lit, b.lit)
    for k in a.counters:
        if k != "tree_reused":
            assert np.array_equal(np.asarray(a.counters[k]), np.asarray(b.counters[k])), k


@pytest.mark.parametrize("method", ["psv", "d_stackless"])
def test_averted_culling_keeps_the_lit_mask(method, precision):
    """The default face culling (closed objects' light-averted triangles) gives the lit
    mask of the unculled tree bit for bit, with about half the casters of the closed
    spheres in the tree and fewer visits."""
    scene, light, gbuf, _ = _scene("sphere_grid")
    on, off = (sl.compute_shadows(scene, gbuf, light, method=method, precision=precision,
                                  face_culling=c) for c in ("averted", "none"))
    assert np.array_equal(on.lit, off.lit)
    assert on.counters["casters"] < 0.6 * off.counters["casters"]
    assert on.counters["tree_nodes"] < off.counters["tree_nodes"]
    assert on.counters["visited_nodes"] < off.counters["visited_nodes"]


def test_reused_tree_gives_the_same_result(precision):
    """reuse_tree keeps the TOP tree of a static light: the next call skips the build
    and equals a rebuilt run; another light, build option, camera (with
    frustum_culling) or a dropped cache builds anew."""

    scene, light, gbuf, _ = _setup("gate")          # a scene of its own: nothing cached
    fresh = sl.compute_shadows(scene, gbuf, light, method="d_hybrid", precision=precision)
    first = sl.compute_shadows(scene, gbuf, light, method="d_hybrid", precision=precision,
                               reuse_tree=True)
    again = sl.compute_shadows(scene, gbuf, light, method="d_stackless", precision=precision,
                               reuse_tree=True)
    assert first.counters["tree_reused"] == 0 and again.counters["tree_reused"] == 1
    assert "build" not in again.timings and "build" in first.timings
    _same(fresh, first)
    _same(sl.compute_shadows(scene, gbuf, light, method="d_stackless", precision=precision),
          again)
    moved = sl.PointLight(position=np.asarray(light.position) + [0.5, 0.0, 0.0])
    other = sl.compute_shadows(scene, gbuf, moved, method="d_stackless", precision=precision,
                               reuse_tree=True)
    assert other.counters["tree_reused"] == 0
    _same(sl.compute_shadows(scene, gbuf, moved, method="d_stackless", precision=precision),
          other)
    seeded = sl.compute_shadows(scene, gbuf, moved, method="d_stackless", precision=precision,
                                reuse_tree=True, seed=3)
    assert seeded.counters["tree_reused"] == 0
    # frustum culling makes the tree depend on the camera
    sl.compute_shadows(scene, gbuf, light, method="psv", precision=precision,
                       reuse_tree=True, frustum_culling=True)
    cam = gbuf.camera.replace(fov_y_deg=gbuf.camera.fov_y_deg * 0.5)
    narrow = sl.render_gbuffer(scene, cam)
    r = sl.compute_shadows(scene, narrow, light, method="psv", precision=precision,
                           reuse_tree=True, frustum_culling=True)
    assert r.counters["tree_reused"] == 0
    _same(sl.compute_shadows(scene, narrow, light, method="psv", precision=precision,
                             frustum_culling=True), r)
    caches.drop(scene)
    r = sl.compute_shadows(scene, narrow, light, method="psv", precision=precision,
                           reuse_tree=True, frustum_culling=True)
    assert r.counters["tree_reused"] == 0


def test_device_node_arrays_live_as_long_as_their_tree():
    """The query's packed node arrays are made once per tree (a reused tree does not
    repack them) and die with it; their contents are node_arrays'."""
    import gc
    import weakref

    scene, light, gbuf, _ = _setup("gate")
    samples = view_samples(gbuf, light)
    tree = psvm.build_tree(scene, light, gbuf.camera, samples, dtype=np.float32,
                           shadow_eps=1e-3, bias="receiver", order="mesh", seed=0,
                           wedge="conservative", classify_ulps=8.0, face_culling="none",
                           frustum_culling=False, build="parallel")[0]
    rows = psvm.device_node_arrays(tree, True)
    assert psvm.device_node_arrays(tree, True) is rows
    for got, want in zip(rows, psvm.node_arrays(tree, True)):
        np.testing.assert_array_equal(np.asarray(got), want)
    cols = psvm.device_node_arrays(tree, False)
    assert len(cols) == 9 and cols is not rows
    probe = weakref.ref(rows[0])
    del tree, rows, cols
    gc.collect()
    assert probe() is None and len(psvm._DEVICE_NODES) == 0


#: the methods' default caster culling (closed objects' light-averted triangles)
DEFAULT_FACE_CULLING = sl.methods.get("psv").options["face_culling"].default


def _query_inputs(scene, light, gbuf, wedge="conservative"):
    """The float32 tree of the methods' defaults (or another ``wedge``) and the query's
    inputs: (tree, samples, points [S, 3], bias scale [S], depth keys [S], homogeneous
    light [4])."""
    samples = view_samples(gbuf, light)
    light_h = sl.scene.view.hard_light(light).homogeneous
    with precision_mode("float32") as dtype:
        tree, scale, _ = psvm.build_tree(scene, light, gbuf.camera, samples, dtype=dtype,
                                         shadow_eps=1e-5, bias="receiver", order="random",
                                         seed=0, wedge=wedge, classify_ulps=64,
                                         face_culling=DEFAULT_FACE_CULLING)
    key = tt.light_key(samples.position, light_h).astype(np.float32)
    return (tree, samples, samples.position.astype(np.float32), scale.astype(np.float32),
            key, light_h)


def test_limits_of_the_packed_lane_state_are_refused(monkeypatch):
    """A lane's state word holds a node id (or, once finished, its visit count) in 27 bits
    and its overflow count in 19: a tree or a lane beyond them is refused with a clear
    error, never wrapped (limits lowered here to the tree and the query at hand)."""
    tree, samples, pts, sc, key, light_h = _query_inputs(*_scene("fuzzy")[:3])
    pts, sc, key = pts[:2000], sc[:2000], key[:2000]
    kw = dict(query="stack", depth_test=True, wedge="conservative", stack_size=4)
    visited = int(psvm.run_query(tree, pts, sc, key, light_h, **kw)["visited"].max())
    monkeypatch.setattr(psvm, "COUNT_MAX", visited)
    psvm.run_query(tree, pts, sc, key, light_h, **kw)             # exact up to the limit
    monkeypatch.setattr(psvm, "COUNT_MAX", visited - 1)
    with pytest.raises(CapacityError, match=f"visited {visited:,} nodes"):
        psvm.run_query(tree, pts, sc, key, light_h, **kw)
    psvm.run_query(tree, pts, sc, key, light_h, **dict(kw, query="stackless"))  # no count
    monkeypatch.setattr(psvm, "NODE_MASK", tree.plane.shape[0] - 2)
    with pytest.raises(CapacityError, match=f"{tree.plane.shape[0]:,} nodes"):
        psvm.run_query(tree, pts, sc, key, light_h, **kw)
    monkeypatch.undo()
    # A finished lane's visit count replaces the node id in its word: a query that could
    # run more steps than that field holds is refused before the chunk that would.
    kw.update(chunk=32, schedule="fixed")
    steps = 32 * psvm.run_query(tree, pts, sc, key, light_h, **kw)["chunks"]
    monkeypatch.setattr(psvm, "VISIT_LIMIT", steps)
    psvm.run_query(tree, pts, sc, key, light_h, **kw)
    monkeypatch.setattr(psvm, "VISIT_LIMIT", steps - 1)
    with pytest.raises(CapacityError, match=f"more than {steps - 1:,} node visits"):
        psvm.run_query(tree, pts, sc, key, light_h, **kw)
    psvm.run_query(tree, pts, sc, key, light_h, **dict(kw, query="stackless"))  # an array


def test_copy_levels_cover_every_stack_in_use():
    for k in (1, 2, 3, 12, 32, 63):
        for stack_pointer_max in range(k + 1):
            m = psvm._copy_levels(stack_pointer_max, k)
            assert max(stack_pointer_max, 1) <= m <= k, (k, stack_pointer_max)
            assert m == k or m & (m - 1) == 0, (k, stack_pointer_max)


@pytest.mark.parametrize("query,depth,stack_size,chunk,tile,in_place", [
    ("stack", False, 3, 1, None, True), ("stack", True, 32, 2, 1024, True),
    ("stack", True, 32, 2, 1024, False), ("hybrid", True, 2, 1, 1024, True)])
def test_compactions_and_spare_stacks_keep_every_result(monkeypatch, request, query, depth,
                                                        stack_size, chunk, tile, in_place):
    """A compaction moves only the stack levels in use, into the tree's spare stack; a
    query on a reused tree starts from the stacks the previous one left (never
    cleared). With chunks of one or two steps (a compaction whenever a bucket shrinks),
    spares poisoned with random node ids, every lane's result and counters equal one
    long chunk's (no compaction) and, on a subset, the plain loop's. ``tile``: lanes run
    in compute tiles of that many lanes (each on a copy of its state; of its stack too
    unless ``in_place``, ``psv.STACK_IN_PLACE``)."""
    import jax.numpy as jnp

    monkeypatch.setattr(psvm, "STACK_IN_PLACE", in_place)
    monkeypatch.setattr(psvm, "COARSE_LANES", 0)          # 4 sizes per octave from 1024
    if tile:
        # Both kernels trace the tile size into their code (the compaction its stack
        # layout): kernels of the default tile must not run here, nor these after.
        monkeypatch.setattr(psvm, "TILE", tile)
        for cached in (psvm._chunk_kernel, psvm._compact_kernel):
            cached.cache_clear()
            request.addfinalizer(cached.cache_clear)
    tiles = []
    real_tile = psvm.tile_size
    monkeypatch.setattr(psvm, "tile_size",
                        lambda b: tiles.append((b, real_tile(b))) or tiles[-1][1])

    tree, samples, pts, sc, key, light_h = _query_inputs(*_scene("fuzzy")[:3])
    # 3,400 lanes: a first bucket of 3,584 (7 x 512) lanes, which later tiles of 1,024
    # do not divide (the stack buffer is rounded up to whole tiles)
    n = 3400
    pts, sc, key = pts[:n], sc[:n], key[:n]
    kw = dict(query=query, depth_test=depth, wedge="conservative", stack_size=stack_size)
    whole = psvm.run_query(tree, pts, sc, key, light_h, chunk=100_000, **kw)
    assert whole["chunks"] <= 2          # hybrid: the stack-only step, then the full one
    levels = []
    real = psvm._compact_kernel
    monkeypatch.setattr(psvm, "_compact_kernel",
                        lambda nb, k, n: levels.append(n) or real(nb, k, n))
    first = psvm.run_query(tree, pts, sc, key, light_h, chunk=chunk, **kw)
    spare = psvm._stack_buffers(tree)
    assert spare and levels
    if stack_size == 32:
        assert any(n < stack_size for n in levels)             # partial copies ran
    rng = np.random.default_rng(1)
    assert all(len(held) == 2 for held in spare.values())    # the stack and the spare
    for size, held in spare.items():
        spare[size] = [jnp.asarray(rng.integers(0, tree.plane.shape[0], size, dtype=np.int32))
                       for _ in held]
    again = psvm.run_query(tree, pts, sc, key, light_h, chunk=chunk, **kw)
    assert bool(tile) == any(t < b for b, t in tiles)       # tiled runs were traced
    for got in (first, again):
        assert got["chunks"] > 10
        for name in ("shadow", "visited", "stack_max", "overflows", "switches"):
            np.testing.assert_array_equal(got[name], whole[name], err_msg=name)
    assert whole["stack_max"].max() >= min(stack_size, 8)     # deep stacks in play
    for i in rng.choice(n, 60, replace=False):
        lit, visited, smax, ov, sw = _plain_query(tree, pts[i], sc[i], key[i], light_h, query,
                                                  depth, stack_size, "conservative")
        assert (lit, visited, smax) == (not again["shadow"][i], again["visited"][i],
                                        again["stack_max"][i]), i
        assert (ov, sw) == (again["overflows"][i], again["switches"][i]), i


def test_chunk_lengths_follow_the_schedule():
    """Fixed: ``chunk`` every time. Adaptive: ``chunk`` first, half of it after a
    check that compacted, doubling up to twice ``chunk`` after checks that did not."""
    fixed = psvm.chunk_lengths(32, "fixed")
    assert [next(fixed)] + [fixed.send(c) for c in (True, False, False)] == [32] * 4
    ada = psvm.chunk_lengths(32, "adaptive")
    got = [next(ada)] + [ada.send(c) for c in (False, False, True, False, False, False, True)]
    assert got == [32, 64, 64, 16, 32, 64, 64, 16]
    one = psvm.chunk_lengths(1, "adaptive")
    assert [next(one)] + [one.send(c) for c in (True, False, False)] == [1, 1, 2, 2]


def test_chunk_schedules_keep_every_result(precision):
    """The adaptive chunk lengths change only when lanes are checked and compacted:
    the lit mask and every counter but ``query_chunks`` equal the fixed schedule's, for
    every query; one compiled chunk kernel per bucket serves every length."""
    scene, light, gbuf, _ = _scene("fuzzy")
    for m in METHODS:
        fixed = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision,
                                   chunk=4, chunk_schedule="fixed")
        ada = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision,
                                 chunk=4)
        assert fixed.counters["query_chunks"] != ada.counters["query_chunks"], m
        fixed.counters.pop("query_chunks"), ada.counters.pop("query_chunks")
        _same(fixed, ada)
    tree, samples, pts, sc, key, light_h = _query_inputs(*_scene("fuzzy")[:3])
    kw = dict(query="stackless", depth_test=True, wedge="conservative", stack_size=0)
    psvm._chunk_kernel.cache_clear()
    got = psvm.run_query(tree, pts[:900], sc[:900], key[:900], light_h, chunk=2, **kw)
    assert got["chunks"] > 3                     # lengths 2, 4 (and on): one bucket
    kernel = psvm._chunk_kernel("stackless", True, "conservative", 0, "lose", "paper",
                                "inside", bool(light_h[3] == 0))
    assert sum(fn is kernel for fn, _ in timing._COMPILED) == 1
    with pytest.raises(ValueError, match="schedule must be one of"):
        psvm.run_query(tree, pts, sc, key, light_h, schedule="geometric", **kw)


@pytest.mark.parametrize("tile", [5, 8])
def test_lane_tiles_keep_every_result(tile, precision):
    """``lane_tile`` only regroups the query's lanes: the lit mask and every counter
    (per-pixel visits, stack use, overflows, switches) equal the row-major run."""
    scene, light, gbuf, _ = _scene("fuzzy")
    for m in METHODS:
        rows = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision)
        tiled = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision,
                                   lane_tile=tile)
        _same(rows, tiled)


@pytest.mark.parametrize("name", ["fuzzy", "gate"])
def test_breadth_first_node_order_keeps_every_result(name, precision):
    """The query on the breadth-first renumbered tree: the same lit mask and every
    counter (visits per pixel, stack use, overflows, switches) as on the tree as built;
    "auto" renumbers only a kept tree (``reuse_tree``)."""
    scene, light, gbuf, _ = _scene(name)
    for m in METHODS:
        built = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision,
                                   node_order="build")
        bfs = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision,
                                 node_order="breadth_first")
        _same(built, bfs)
        assert "renumber" in bfs.timings and "renumber" not in built.timings
    auto = sl.compute_shadows(scene, gbuf, light, method="d_stackless", precision=precision)
    kept = sl.compute_shadows(scene, gbuf, light, method="d_stackless", precision=precision,
                              reuse_tree=True)
    assert "renumber" not in auto.timings and "renumber" in kept.timings
    _same(auto, kept)
    caches.drop(scene)


def test_lane_tile_reaches_the_query(monkeypatch):
    """The option is not ignored: ``_run`` hands run_query the tile order (and no order
    at ``lane_tile=1``), and run_query refuses an order that is not a permutation."""
    scene, light, gbuf, _ = _scene("gate")
    seen = []
    real = psvm.run_query

    def spy(*args, lane_order=None, **kwargs):
        seen.append(lane_order)
        return real(*args, lane_order=lane_order, **kwargs)

    monkeypatch.setattr(psvm, "run_query", spy)
    sl.compute_shadows(scene, gbuf, light, method="d_stackless", lane_tile=8)
    sl.compute_shadows(scene, gbuf, light, method="d_stackless")
    expected = view_samples(gbuf, light).tile_order(8)
    assert np.array_equal(seen[0], expected) and not np.array_equal(
        expected, np.arange(expected.size))
    assert seen[1] is None
    monkeypatch.undo()
    with precision_mode("float32") as dt:
        tree, scale, _ = psvm.build_tree(scene, light, gbuf.camera, view_samples(gbuf, light),
                                         dtype=dt, shadow_eps=1e-4, bias="receiver",
                                         order="random", seed=0, wedge="conservative",
                                         classify_ulps=64, face_culling="none",
                                         frustum_culling=False, build="parallel")
        pts = np.zeros((4, 3), dt)
        with pytest.raises(ValueError, match="permutation of the 4 points"):
            psvm.run_query(tree, pts, np.ones(4, dt), np.zeros(4, dt),
                           np.asarray(light.homogeneous, np.float64), query="stackless",
                           depth_test=True, wedge="conservative", stack_size=0,
                           lane_order=[0, 0, 1, 2])


def test_tile_order_groups_pixels_by_tile():
    """Samples.tile_order against a plain loop over the tiles and their pixels."""
    scene, light, gbuf, _ = _scene("gate")
    samples = view_samples(gbuf, light)
    h, w = samples.shape
    tile = 6                                    # does not divide 64: partial tiles
    at = {int(i): k for k, i in enumerate(samples.index)}
    expected = [at[y * w + x]
                for ty in range(0, h, tile) for tx in range(0, w, tile)
                for y in range(ty, min(ty + tile, h)) for x in range(tx, min(tx + tile, w))
                if y * w + x in at]
    assert samples.tile_order(tile).tolist() == expected
    assert samples.tile_order(1).tolist() == list(range(samples.count))


@pytest.mark.parametrize("name,stack_size,stall_limit", [
    ("sphere_grid", 12, None), ("fuzzy", 2, None), ("sphere_grid", 12, 9)])
def test_hybrid_counts_in_the_word_equal_the_array(monkeypatch, name, stack_size,
                                                   stall_limit):
    """HYBRID_FAST_IN_WORD: the stack-only chunks keep visit counts in the state word
    until the first stall (or until a stall step would not fit its field: a limit of 9
    steps here), then the array takes over. Every counter and the lit mask equal the
    runs that keep the array throughout, with no stall, with switches, and past the
    limit; the visits also equal the plain loop's."""
    scene, light, gbuf, _ = _scene(name)
    runs, moves = {}, []
    real_run = psvm.StageTimer.run

    def counting_run(self, stage, fn, *args):
        if fn is psvm._visits_to_array:
            moves.append(stage)
        return real_run(self, stage, fn, *args)
    monkeypatch.setattr(psvm.StageTimer, "run", counting_run)
    if stall_limit is not None:
        monkeypatch.setattr(psvm, "STALL_STEP_MAX", stall_limit)
    for flag in (False, True):
        monkeypatch.setattr(psvm, "HYBRID_FAST_IN_WORD", flag)
        runs[flag] = sl.compute_shadows(scene, gbuf, light, method="d_hybrid",
                                        stack_size=stack_size, chunk=4)
    _same(runs[False], runs[True])
    switches = runs[True].counters["stackless_switches"]
    assert (switches > 0) == (stack_size == 2)
    assert runs[True].counters["query_chunks"] > 10
    # the counts left the word once where a lane stalled or the limit came, else never
    assert len(moves) == (0 if switches == 0 and stall_limit is None else 1)
    tree, samples, pts, sc, key, light_h = _query_inputs(scene, light, gbuf)
    got = runs[True].counters["visited_nodes_per_pixel"].reshape(-1)[samples.index]
    for i in np.random.default_rng(2).choice(samples.count, 40, replace=False):
        assert _plain_query(tree, pts[i], sc[i], key[i], light_h, "hybrid", True,
                            stack_size, "conservative")[1] == got[i], i


def test_visits_move_from_the_word_to_the_array():
    """_visits_to_array on hand-made lanes: a finished lane's count from its node field,
    a stalled lane's from its stats count field, a running lane's = the query's steps so
    far, padding 0; the count field cleared, stack pointer and maximum kept."""
    DONE, STALL, SHADOW = psvm.DONE, int(psvm.STALL), psvm.SHADOW
    word = np.array([DONE | 17, DONE | SHADOW | 3, STALL | 40, 12, DONE], np.int32)
    stats = np.array([5 | (7 << 6), 0, 3 | (4 << 6) | (21 << 12), 2 | (2 << 6), 0], np.int32)
    visited, new = psvm._visits_to_array(word, stats, np.int32(30))
    assert np.asarray(visited).tolist() == [17, 3, 21, 30, 0]
    assert np.asarray(new).tolist() == [5 | (7 << 6), 0, 3 | (4 << 6), 2 | (2 << 6), 0]


def test_a_tree_is_queried_with_its_own_wedge():
    """A signed tree's wedge field is a packed interval, a symmetric tree's a bound: a
    query with the other wedge mode is refused (JAX and the Warp kernels)."""
    from shadowlab.kernels import psv as kpsv
    scene, light, gbuf, _ = _scene("gate")
    for built, asked in (("signed", "conservative"), ("conservative", "signed"),
                         ("signed", "vertex")):
        tree, samples, pts, sc, key, light_h = _query_inputs(scene, light, gbuf, built)
        for run in (psvm.run_query, kpsv.query):
            with pytest.raises(ValueError, match="does not match the tree"):
                run(tree, pts, sc, key, light_h, query="stack", depth_test=True,
                    wedge=asked, stack_size=4)


def test_stack_overflow_is_detected_and_hybrid_switches():
    scene, light, gbuf, truth = _scene("fuzzy")
    r = sl.compute_shadows(scene, gbuf, light, method="psv", stack_size=1)
    ov = r.counters["stack_overflows_per_pixel"]
    assert r.counters["overflow_pixels"] > 0
    assert r.counters["overflow_pixels"] == np.count_nonzero(ov)
    assert r.counters["stack_overflows"] == ov.sum()
    assert r.counters["stack_max"] == 1
    wrong = (r.lit != truth) & gbuf.valid
    assert not np.any(wrong & (ov == 0))        # errors only where the stack overflowed
    h = sl.compute_shadows(scene, gbuf, light, method="d_hybrid", stack_size=1)
    assert h.counters["stackless_switches"] > 0
    assert h.counters["stack_max"] <= 1
    assert np.count_nonzero((h.lit != truth) & gbuf.valid) == 0


# --------------------------------------------------------------------------- plain loops

def _plain_query(tree, p, scale, key, light_h, query, depth_test, stack_size, wedge):
    """One sample, one node at a time (Python), mirroring docs/psv.md."""
    plane, pos, inter = tree.plane, tree.pos, tree.inter
    dist = 1.0 if light_h[3] == 0 else float(np.linalg.norm(p.astype(np.float64) - light_h[:3]))
    lo, hi = psvm.wedge_interval_as_queried(tree)     # lo = -wedge unless signed
    node, twice, stack, sl, ret = tree.root, False, [], query == "stackless", -1
    visited = smax = overflows = switches = 0
    while node >= 0:
        visited += 1
        sv, cap = node >> 2, (node & 3) == 3
        off = float(p[0] * plane[node, 0] + p[1] * plane[node, 1] + p[2] * plane[node, 2]
                    + plane[node, 3])
        inside = (off * scale < tree.bound[sv]) if cap else off >= 0
        wok = cap or wedge == "off" or (lo[node] * dist - tree.margin <= off
                                        <= hi[node] * dist + tree.margin)
        skip = depth_test and (node & 3) == 0 and key < tree.depth[sv]
        if query == "hybrid" and sl and twice and node == ret:
            sl = False
        if sl:
            if skip:
                node, twice = int(tree.anc[sv]), True
            elif not twice and inter[node] >= 0 and wok:
                node = int(inter[node])
            else:
                twice = False
                if not inside:
                    if pos[node] >= 0:
                        node = int(pos[node])
                    else:
                        node, twice = int(tree.anc[sv]), True
                elif cap:
                    return False, visited, smax, overflows, switches
                else:
                    node += 1
            continue
        if skip:
            node = stack.pop() if stack else -1
            continue
        if inter[node] >= 0 and wok and not twice:
            if len(stack) < stack_size:
                stack.append(int(inter[node]))
                smax = max(smax, len(stack))
            elif query == "hybrid":
                sl, ret, switches, node = True, node, switches + 1, int(inter[node])
                continue
            else:
                overflows += 1
        twice = False
        if not inside:
            node = int(pos[node]) if pos[node] >= 0 else (stack.pop() if stack else -1)
        elif cap:
            return False, visited, smax, overflows, switches
        else:
            node += 1
    return True, visited, smax, overflows, switches


@pytest.mark.parametrize("method,query,depth,stack,wedge", [
    ("psv", "stack", False, 2, "conservative"), ("d_psv", "stack", True, 3, "conservative"),
    ("d_stackless", "stackless", True, 0, "conservative"),
    ("d_hybrid", "hybrid", True, 2, "conservative"),
    ("psv", "stack", False, 2, "signed"), ("d_stackless", "stackless", True, 0, "signed"),
    ("d_hybrid", "hybrid", True, 2, "signed")])
def test_counters_against_plain_loop(method, query, depth, stack, wedge):
    scene, light, gbuf, _ = _scene("sphere_grid", res=24)
    kw = {} if query == "stackless" else {"stack_size": stack}
    r = sl.compute_shadows(scene, gbuf, light, method=method, wedge=wedge, **kw)
    tree, samples, pts, sc, key, light_h = _query_inputs(scene, light, gbuf, wedge)
    got = {k: r.counters[k][np.unravel_index(samples.index, gbuf.valid.shape)]
           for k in r.counters if k.endswith("_per_pixel")}
    lit = r.lit.reshape(-1)[samples.index]
    for i in range(samples.count):
        l, v, smax, ov, sw = _plain_query(tree, pts[i], sc[i], key[i], light_h, query, depth,
                                          stack, wedge)
        assert l == lit[i] and v == got["visited_nodes_per_pixel"][i], i
        if query != "stackless":
            assert smax == got["stack_max_per_pixel"][i]
        if query == "stack":
            assert ov == got["stack_overflows_per_pixel"][i]
        if query == "hybrid":
            assert sw == got["stackless_switches_per_pixel"][i]


# --------------------------------------------------------------------------- directional lights

def _directional(name, direction, res=48):
    params = SCENES[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    light = sl.DirectionalLight(direction)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    return scene, light, gbuf, sl.reference_shadows(scene, gbuf, light)


@pytest.mark.parametrize("name,direction", [("gate", (0.3, -1.0, -0.4)),
                                            ("sphere_grid", (-0.5, -1.0, 0.2)),
                                            ("fuzzy", (0.7, -0.6, 0.1))])
def test_directional_light_queries_equal_reference(name, direction, precision):
    scene, light, gbuf, truth = _directional(name, direction)
    assert 0 < truth[gbuf.valid].mean() < 1          # both lit and shadowed samples
    for m in METHODS:
        r = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision)
        ok = gbuf.valid
        if m in ("psv", "d_psv"):
            ok = ok & (r.counters["stack_overflows_per_pixel"] == 0)
        assert np.count_nonzero((r.lit != truth) & ok) == 0, m
    for opts in ({"wedge": "vertex"}, {"order": "distance"}, {"frustum_culling": True},
                 {"stack_size": 1}):
        r = sl.compute_shadows(scene, gbuf, light, method="d_hybrid", precision=precision,
                               **opts)
        assert np.count_nonzero((r.lit != truth) & gbuf.valid) == 0, opts


def test_directional_light_counters_and_builds():
    scene, light, gbuf, _ = _directional("sphere_grid", (-0.5, -1.0, 0.2), res=20)
    samples = view_samples(gbuf, light)
    light_h = sl.scene.view.hard_light(light).homogeneous
    assert light_h[3] == 0
    with precision_mode("float32") as dtype:
        trees = [psvm.build_tree(scene, light, gbuf.camera, samples, dtype=dtype,
                                 shadow_eps=1e-5, bias="receiver", order="random", seed=0,
                                 wedge="conservative", classify_ulps=64, build=b,
                                 face_culling=DEFAULT_FACE_CULLING)[0]
                 for b in ("parallel", "sequential")]
    assert trees[0].same_as(trees[1]) == []
    tree = trees[0]
    # Depth keys: -dot(towards light, p), the smallest over each merged triangle.
    merged = tree.status == tt.STATUS_MERGED
    keys = tt.triangle_key(scene.triangles[tree.tri[merged]], light_h)
    assert np.all(tree.depth[merged] <= keys - tree.margin + 1e-6)
    key = tt.light_key(samples.position, light_h).astype(np.float32)
    pts = samples.position.astype(np.float32)
    with precision_mode("float32"):
        _, scale, _ = psvm.build_tree(scene, light, gbuf.camera, samples, dtype=np.float32,
                                      shadow_eps=1e-5, bias="receiver", order="random", seed=0,
                                      wedge="conservative", classify_ulps=64,
                                      face_culling=DEFAULT_FACE_CULLING)
    sc = scale.astype(np.float32)
    for method, query, depth, stack in (("d_psv", "stack", True, 3),
                                        ("d_stackless", "stackless", True, 0),
                                        ("d_hybrid", "hybrid", True, 2)):
        kw = {} if query == "stackless" else {"stack_size": stack}
        r = sl.compute_shadows(scene, gbuf, light, method=method, **kw)
        got = r.counters["visited_nodes_per_pixel"].reshape(-1)[samples.index]
        lit = r.lit.reshape(-1)[samples.index]
        for i in range(samples.count):
            l, v, *_ = _plain_query(tree, pts[i], sc[i], key[i], light_h, query, depth, stack,
                                    "conservative")
            assert l == lit[i] and v == got[i], (method, i)


# --------------------------------------------------------------------------- grazing samples

def _grazing(name, count=1024, seed=3):
    """A G-buffer [32, count // 32] of points whose segment to the light passes through a
    caster's edge (float64): each sample's result is decided by the rounding of one
    edge plane, so every method must evaluate the very same planes as brute_force.

    Extracted from the fuzzy-100k bench case, where all 18 mismatches against the Embree
    reference lie within float32 rounding of a sliver's edge (docs/psv.md).
    """
    params = SCENES[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    light = sl.scene.view.hard_light(view.light).homogeneous[:3]
    rng = np.random.default_rng(seed)
    # Edges of the casters nearest the light, samples just behind them: few other
    # casters decide these samples.
    near = np.argsort(tt.triangle_key(scene.triangles, np.append(light, 1.0)))
    tri = scene.triangles[near[rng.integers(0, max(count // 8, 1), count)]]
    e = rng.integers(0, 3, count)
    s = rng.uniform(0.1, 0.9, count)[:, None]
    a, b = tri[np.arange(count), e], tri[np.arange(count), (e + 1) % 3]
    q = a + s * (b - a)                                 # a point on the edge
    p = light + (q - light) * rng.uniform(1.002, 1.02, count)[:, None]
    n = (light - p) / np.linalg.norm(light - p, axis=1, keepdims=True)
    shape = (32, count // 32)
    gbuf = sl.GBuffer(p.reshape(*shape, 3), n.reshape(*shape, 3), np.ones(shape),
                      np.zeros(shape, np.int32), np.ones(shape, bool),
                      view.camera.replace(resolution=shape[::-1]))
    return scene, view.light, gbuf


@pytest.mark.parametrize("name", ["fuzzy", "gate"])
def test_grazing_samples_equal_brute_force(name, precision):
    """Regression: the queries decide with brute_force's planes, bit for bit (they used
    planes of another jitted setup, 1 ulp apart on most triangles, and disagreed with
    brute_force on grazing samples)."""
    scene, light, gbuf = _grazing(name)
    bf = sl.compute_shadows(scene, gbuf, light, method="brute_force", precision=precision)
    assert 0.05 < bf.lit.mean() < 0.95
    for m in METHODS:
        r = sl.compute_shadows(scene, gbuf, light, method=m, precision=precision)
        if m in ("psv", "d_psv"):
            assert r.counters["overflow_pixels"] == 0
        assert np.count_nonzero(r.lit != bf.lit) == 0, m
