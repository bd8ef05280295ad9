"""clustered_ptsv / ptsv: hierarchy vs loops, planes, traversal counters vs a plain
per-triangle loop, and exactness against the reference for option combinations."""

import functools

import jax

import jax.numpy as jnp
import numpy as np
import pytest

import shadowlab as sl
from shadowlab.geometry.triangle_setup import shadow_volume_planes
from shadowlab.structures import cluster_hierarchy as ch
from shadowlab.methods.clustered_ptsv import post_perspective_planes, run_traversal_method
from shadowlab.methods import clustered_ptsv as clustered
from shadowlab.scene.procedural import default_view

# One resolution for every test, and small scenes: with the methods' minimum triangle and
# sample buckets, every scene here shares the compiled kernels of an option set.
RES = 48
SMALL = {"gate": {"trees": 4, "leaves_per_tree": 60, "bars": 5},
         "sphere_grid": {"n": 3, "triangles_per_sphere": 120},
         "fuzzy": {"triangles": 1500, "clusters": 4},
         "terrain": {"size": 16}, "blobs": {"grid": 16, "blobs": 3},
         "soup": {"count": 150}}
SCENES = sorted(SMALL)


@functools.lru_cache(maxsize=None)
def _setup(name, res=RES):
    scene = sl.load_scene(name, **SMALL[name])
    view = default_view(name, scene, **SMALL[name])
    cam = view.camera.replace(resolution=(res, res))
    gbuf = sl.render_gbuffer(scene, cam)
    truth = sl.reference_shadows(scene, gbuf, view.light)
    return scene, gbuf, view.light, truth


def _mismatches(res, truth, gbuf):
    return int(((res.lit != truth) & gbuf.valid).sum())


# Three option sets cover every value of every option (with the cap bias below); each
# runs on every scene (kernels are compiled once per option set, not per scene).
COMBOS = [
    dict(),
    dict(bounds="implicit", culling_planes=False, passes=2, expand_level=2, prune=True,
         wave=64, bias_reject=True),
    dict(storage="full", front_face_culling=False, leaf_samples="cluster",
         depth_slices="scaled", z_bits=4),
]


@pytest.mark.parametrize("opts", COMBOS, ids=["default", "implicit-2pass-prune", "full-noffc-z4"])
def test_clustered_equals_reference(opts):
    for name in SCENES:
        scene, gbuf, light, truth = _setup(name)
        res = sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv", **opts)
        assert _mismatches(res, truth, gbuf) == 0, (name, opts)


@pytest.mark.parametrize("method", ["clustered_ptsv", "ptsv"])
def test_float64_equals_reference(method):
    for name in ("gate", "soup", "terrain"):
        scene, gbuf, light, truth = _setup(name)
        res = sl.compute_shadows(scene, gbuf, light, method=method, precision="float64")
        assert _mismatches(res, truth, gbuf) == 0, name


def test_cap_bias_equals_brute_force():
    for name in ("gate", "soup", "sphere_grid"):
        scene, gbuf, light, _ = _setup(name)
        bf = sl.compute_shadows(scene, gbuf, light, method="brute_force", bias="cap")
        for method in ("clustered_ptsv", "ptsv"):
            res = sl.compute_shadows(scene, gbuf, light, method=method, bias="cap")
            assert np.array_equal(res.lit, bf.lit), (name, method)


@pytest.mark.parametrize("opts", [dict(), dict(culling_planes=False, passes=2, prune=True,
                                               wave=64, front_face_culling=False)],
                         ids=["default", "2pass-prune-noffc"])
def test_ptsv_equals_reference(opts):
    for name in SCENES:
        scene, gbuf, light, truth = _setup(name)
        res = sl.compute_shadows(scene, gbuf, light, method="ptsv", **opts)
        assert _mismatches(res, truth, gbuf) == 0, (name, opts)


def test_full_depth_buffer_build_plane_sets_and_paper_options():
    """Both plane sets are exact on both trees (plane_set, the head-to-head of Fig. 6);
    tree_samples="all" (the 2011 build over every valid pixel) is exact, tests the
    light-averted samples too (so needs more test-and-sets than the light-facing build)
    and leaves them unlit; the papers' configuration (PAPER_OPTIONS) equals brute force
    up to lost shadows (front-face culling of the light-facing side drops them where a
    receiver lies within the bias inside a closed object; never a false shadow)."""
    from shadowlab.methods.clustered_ptsv import PAPER_OPTIONS

    scene, gbuf, light, truth = _setup("gate")
    facing = sl.compute_shadows(scene, gbuf, light, method="ptsv")
    full = sl.compute_shadows(scene, gbuf, light, method="ptsv", tree_samples="all")
    assert _mismatches(full, truth, gbuf) == 0
    assert full.counters["samples"] == int(gbuf.valid.sum()) > facing.counters["samples"]
    assert full.counters["tests"] > facing.counters["tests"]
    for method in ("clustered_ptsv", "ptsv"):            # either plane set on either tree
        for plane_set in ("per_vertex", "silhouette"):
            res = sl.compute_shadows(scene, gbuf, light, method=method, plane_set=plane_set)
            assert _mismatches(res, truth, gbuf) == 0, (method, plane_set)
            assert res.counters["extra_plane_rejects"] > 0
        res = sl.compute_shadows(scene, gbuf, light, method=method, **PAPER_OPTIONS[method])
        bad = (res.lit != truth) & gbuf.valid
        assert not np.any(bad & ~res.lit), method            # never a false shadow
        assert res.counters["front_face_culled"] > 0


def test_face_culling_sides_with_receivers_inside_closed_objects():
    """The gate's parts touch and interpenetrate (bars in the lintel, rails in the posts,
    posts in the ground), so with a larger bias some shadow rays start inside a closed
    object. Dropping its light-facing triangles (the papers' front-face culling) then
    loses those shadows; dropping the light-averted ones is exact (the last crossing
    towards the light is always light-facing)."""
    scene, gbuf, light, _ = _setup("gate")
    truth = sl.reference_shadows(scene, gbuf, light, shadow_eps=3e-4)
    lost = {}
    for method in ("clustered_ptsv", "ptsv"):
        for side in ("facing", "averted"):
            res = sl.compute_shadows(scene, gbuf, light, method=method, shadow_eps=3e-4,
                                     front_face_culling=True, cull_side=side)
            bad = (res.lit != truth) & gbuf.valid
            assert not np.any(bad & ~res.lit), (method, side)     # never a false shadow
            lost[method, side] = int(bad.sum())
            assert res.counters["front_face_culled"] > 0
    assert lost["clustered_ptsv", "averted"] == 0 and lost["ptsv", "averted"] == 0
    assert lost["clustered_ptsv", "facing"] > 0 and lost["ptsv", "facing"] > 0


def test_frames_share_compiled_kernels():
    """Frames at one resolution whose triangle and sample counts fall in the same buckets
    share compiled kernels: camera floats are data, shapes are bucketed. The test warms
    its own kernels on gate (the test session may drop every executable between tests,
    see ``core.executables.guard``), then runs gate from another camera and two other
    scenes of the same triangle bucket."""
    scene, gbuf, light, _ = _setup("gate")
    sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv")     # warm-up: compiles
    cam = gbuf.camera
    moved = cam.replace(eye=cam.target + 1.1 * (cam.eye - cam.target)
                        + np.array([0.3, 0.2, -0.2]) * np.linalg.norm(cam.eye - cam.target))
    moved_gbuf = sl.render_gbuffer(scene, moved)
    assert not np.array_equal(moved_gbuf.position, gbuf.position)      # really another view
    frames = [(scene, moved_gbuf, light)] + [_setup(name)[:3] for name in
                                             ("sphere_grid", "terrain")]  # < MIN_TRIANGLES
    for scene, gbuf, light in frames:
        res = sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv")
        compile_s = {k: v for k, v in res.timings.items() if k.endswith("_compile")}
        assert compile_s and all(v == 0.0 for v in compile_s.values()), (scene.name, compile_s)


# --------------------------------------------------------------------------- hierarchy

def _samples_of(name, res=RES):
    scene, gbuf, light, _ = _setup(name, res)
    from shadowlab.core.frame import view_samples
    return scene, gbuf, light, view_samples(gbuf, light)


def test_keys_masks_and_boxes_against_loops():
    scene, gbuf, light, smp = _samples_of("gate")
    cam = gbuf.camera
    tree = ch.cluster_layout(cam)
    w = gbuf.shape[1]
    px, py = smp.index % w, smp.index // w
    with jax.enable_x64(True):
        coords = ch.sample_coords(tree, jnp.asarray(smp.position), jnp.asarray(cam.view_matrix()))
        keys, _ = ch.sample_keys(tree, jnp.asarray(px), jnp.asarray(py), coords)
        keys = np.asarray(keys)
        depth = gbuf.depth.reshape(-1)[smp.index]
        ref = ch.sample_keys_numpy(tree, px, py, depth)
        # float64 log in JAX vs math.log: equal except exactly at slice boundaries
        assert np.mean(keys == ref) > 0.999
        valid = jnp.ones(len(keys), bool)
        scale = jnp.asarray(np.linspace(0.5, 2, len(keys)))
        _, table = ch.tile_slots(tree, jnp.asarray(px), jnp.asarray(py), valid)
        for storage in ("full", "compact"):
            h = ch.build(tree, jnp.asarray(keys), valid, coords, scale, storage,
                         **_tiles(keys, table))
            for lvl, (a, b) in enumerate(zip(h.masks, ch.masks_numpy(tree, keys))):
                np.testing.assert_array_equal(np.asarray(a), b, err_msg=f"level {lvl}")
            # compact entries carry their keys: the inverse of the pointers
            for lvl in range(1, tree.levels + 1):
                if h.keys is None:
                    assert storage == "full"
                    continue
                ptr, ek = np.asarray(h.ptr[lvl - 1]), np.asarray(h.keys[lvl - 1])
                live = np.flatnonzero(ptr >= 0)
                assert len(live) == int(h.counts[lvl - 1]) > 0
                np.testing.assert_array_equal(ek[ptr[live]], live, err_msg=f"level {lvl}")
                assert not ek[len(live):].any()
            # boxes (leaf level and one inner level) against a loop over samples
            c = np.asarray(coords)
            for lvl in (tree.levels, 2):
                node = keys >> tree.shift(lvl)
                lo, hi = np.asarray(h.lo[lvl - 1]), np.asarray(h.hi[lvl - 1])
                sm = np.asarray(h.smin[lvl - 1])
                ptr = None if h.ptr is None else np.asarray(h.ptr[lvl - 1])
                for k in np.unique(node)[:50]:
                    sel = node == k
                    i = k if ptr is None else ptr[k]
                    assert np.all(lo[i] <= c[sel].min(0)) and np.all(hi[i] >= c[sel].max(0))
                    np.testing.assert_allclose(lo[i], c[sel].min(0), rtol=1e-9, atol=1e-12)
                    np.testing.assert_allclose(hi[i], c[sel].max(0), rtol=1e-9, atol=1e-12)
                    assert sm[i] == np.asarray(scale)[sel].min()
            # implicit boxes contain the samples' coordinates
            for lvl in range(1, tree.levels + 1):
                ilo, ihi = ch.implicit_bounds(tree, lvl, jnp.asarray(keys >> tree.shift(lvl)),
                                              np.float64)
                assert np.all(np.asarray(ilo) <= c) and np.all(np.asarray(ihi) >= c), lvl


@functools.partial(jax.jit, static_argnames=("tree", "storage", "caps"))
def _full_tree_build(tree, storage, caps, keys, valid, coords, scale):
    """The previous build, kept as the reference: a bool per leaf of the key space, the
    existence pyramid and masks packed from it, starts as prefix sums over whole levels,
    boxes scattered from the samples (compact: to start + popcount, inner levels from
    the children). Same outputs as ``cluster_hierarchy._build``, at any size."""
    d = tree.levels
    big = jnp.asarray(np.finfo(coords.dtype).max, coords.dtype)
    exists = [jnp.zeros(tree.nodes(d), bool).at[jnp.where(valid, keys, tree.nodes(d))].set(
        True, mode="drop")]
    for level in range(d - 1, 0, -1):
        exists.insert(0, jnp.any(exists[0].reshape(tree.nodes(level), -1), axis=1))
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(32, dtype=jnp.uint32))
    masks = [jnp.sum(jnp.zeros(tree.nodes(lv) * 32, bool).at[: e.shape[0]].set(e).reshape(
        -1, 32).astype(jnp.uint32) * weights, axis=1, dtype=jnp.uint32)
        for lv, e in enumerate(exists)]
    counts = tuple(jnp.sum(jax.lax.population_count(m).astype(jnp.int32)) for m in masks)
    los, his, sms = [None] * d, [None] * d, [None] * d
    starts = None
    if storage == "full":
        idx = jnp.where(valid, keys.astype(jnp.int32), caps[-1])
    else:
        starts = [jnp.cumsum(c) - c for c in
                  (jax.lax.population_count(m).astype(jnp.int32) for m in masks)]
        idx = jnp.where(valid, ch.child_index(masks, starts, d, keys), caps[-1])
    los[-1] = jnp.full((caps[-1], 3), big).at[idx].min(coords, mode="drop")
    his[-1] = jnp.full((caps[-1], 3), -big).at[idx].max(coords, mode="drop")
    sms[-1] = jnp.full((caps[-1],), big).at[idx].min(scale, mode="drop")
    ekey = jnp.zeros(caps[-1], jnp.uint32).at[idx].set(keys, mode="drop")
    for level in range(d - 1, 0, -1):
        if storage == "full":
            n = tree.nodes(level)
            los[level - 1] = jnp.min(los[level].reshape(n, -1, 3), axis=1)
            his[level - 1] = jnp.max(his[level].reshape(n, -1, 3), axis=1)
            sms[level - 1] = jnp.min(sms[level].reshape(n, -1), axis=1)
            continue
        cap = caps[level - 1]
        live = jnp.arange(caps[level]) < counts[level]
        pkey = ekey >> 5
        parent = jnp.where(live, ch.child_index(masks, starts, level, pkey), cap)
        los[level - 1] = jnp.full((cap, 3), big).at[parent].min(los[level], mode="drop")
        his[level - 1] = jnp.full((cap, 3), -big).at[parent].max(his[level], mode="drop")
        sms[level - 1] = jnp.full((cap,), big).at[parent].min(sms[level], mode="drop")
        ekey = jnp.zeros(cap, jnp.uint32).at[parent].set(pkey, mode="drop")
    lo, hi = [], []
    for level, (a, b) in enumerate(zip(los, his)):
        if storage == "full":
            pa, pb = ch.pad_box(a, b, a.dtype)
        else:              # whole chunks up to the count are padded, later rows keep their fill
            e = min(a.shape[0], ch.ENTRY_CHUNK)
            live = (jnp.arange(a.shape[0]) < (counts[level] + e - 1) // e * e)[:, None]
            pa, pb = ch.pad_box(a, b, a.dtype)
            pa, pb = jnp.where(live, pa, a), jnp.where(live, pb, b)
        lo.append(pa)
        hi.append(pb)
    return masks, exists, counts, starts, lo, hi, sms


def _assert_same_hierarchy(new, ref, caps):
    masks, exists, counts, starts, lo, hi, smin = ref
    tree = new.tree
    for lvl in range(tree.levels):
        np.testing.assert_array_equal(np.asarray(new.masks[lvl]), np.asarray(masks[lvl]))
        np.testing.assert_array_equal(np.asarray(new.exists[lvl]), np.asarray(exists[lvl]))
        assert int(new.counts[lvl]) == int(counts[lvl])
        for a, b in ((new.lo, lo), (new.hi, hi), (new.smin, smin)):
            assert a[lvl].shape == (caps[lvl],) + b[lvl].shape[1:]
            np.testing.assert_array_equal(np.asarray(a[lvl]), np.asarray(b[lvl]))
        if starts is None:
            assert new.start is None
            continue
        # start: equal on existing nodes (the only ones read), 0 on absent ones
        word = np.asarray(masks[lvl])
        has = (word != 0) | (np.arange(len(word)) == 0)
        got = np.asarray(new.start[lvl])
        np.testing.assert_array_equal(got[has], np.asarray(starts[lvl])[has])
        assert not got[~has].any()
    if new.ptr is not None:                       # the paper's pointers, from the masks
        for lvl in range(1, tree.levels + 1):
            want = np.where(np.asarray(exists[lvl - 1]), 0, -1)
            rows = np.flatnonzero(want == 0)
            want[rows] = np.arange(len(rows))
            np.testing.assert_array_equal(np.asarray(new.ptr[lvl - 1]), want)


def _build_inputs(name, kind, precision, z_bits=0, depth_slices="clamp"):
    """Keys, validity, coordinates, bias scales (with zeros) and tile table of a scene's
    light-facing samples, padded to 4096 rows as the pipeline pads them."""
    scene, gbuf, light, smp = _samples_of(name)
    cam = gbuf.camera
    tree = (ch.cluster_layout(cam, z_bits, depth_slices) if kind == "cluster"
            else ch.ptsv_layout(cam))
    dtype = np.float64 if precision == "float64" else np.float32
    s, n = 4096, smp.count
    w = gbuf.shape[1]
    px = jnp.asarray(np.pad(smp.index % w, (0, s - n)), jnp.int32)
    py = jnp.asarray(np.pad(smp.index // w, (0, s - n)), jnp.int32)
    valid = jnp.arange(s) < n
    pos = jnp.asarray(np.pad(smp.position, ((0, s - n), (0, 0))), dtype)
    coords = ch.sample_coords(tree, pos, jnp.asarray(cam.view_matrix(), dtype))
    coords = jnp.where(valid[:, None], coords, coords[0])
    keys, _ = ch.sample_keys(tree, px, py, coords)
    scale = jnp.asarray(np.random.default_rng(1).choice([0.0, 0.3, 1.0, 2.0], s), dtype)
    return tree, keys, valid, coords, scale, ch.tile_slots(tree, px, py, valid)[1]


def _tiles(keys, table):
    """The build's per-tile arguments from the tile table (as the sample stage makes
    them)."""
    keys = jnp.asarray(keys)
    return dict(tile_keys=keys[jnp.minimum(table, keys.shape[0] - 1)],
                tile_valid=table < keys.shape[0])


def _caps(tree, storage, s):
    s = -(-s // ch.ENTRY_CHUNK) * ch.ENTRY_CHUNK
    return tuple(tree.nodes(lv) if storage == "full" else min(tree.nodes(lv), s)
                 for lv in range(1, tree.levels + 1))


BUILD_CASES = {"float32": [("fuzzy", "cluster", {}, "compact"), ("gate", "cluster", {}, "full"),
                           ("soup", "ptsv", {}, "compact")],
               "float64": [("fuzzy", "cluster", {}, "compact"),
                           ("sphere_grid", "cluster", dict(z_bits=4, depth_slices="scaled"),
                            "compact")]}


@pytest.mark.parametrize("precision", sorted(BUILD_CASES))
def test_build_equals_the_full_tree_build(precision):
    """The sample-proportional build (tile dedupe, bottom-up masks over the clusters,
    top-down starts) gives the previous full-tree build's masks, counts, starts, boxes
    and smin bit for bit: cluster tree (default key; a 4-bit z key with scaled slices)
    and PTSV tree, both storages; fuzzy has tiles with many clusters."""
    with jax.enable_x64(precision == "float64"):
        for name, kind, opts, storage in BUILD_CASES[precision]:
            tree, keys, valid, coords, scale, table = _build_inputs(name, kind, precision,
                                                                    **opts)
            caps = _caps(tree, storage, keys.shape[0])
            new = ch.build(tree, keys, valid, coords, scale, storage, **_tiles(keys, table))
            ref = _full_tree_build(tree, storage, caps, keys, valid, coords, scale)
            _assert_same_hierarchy(new, ref, caps)
            assert int(new.counts[-1]) == len(np.unique(np.asarray(keys)[np.asarray(valid)]))


def test_build_keeps_counters_and_lit_masks(monkeypatch):
    """The whole method with the reference build in its place gives the same counters
    and lit mask (the starts of absent nodes, now 0, are never read)."""
    real = ch.build

    def reference(tree, keys, valid, coords, scale, storage="compact", **tiles):
        caps = _caps(tree, storage, keys.shape[0])
        m, _, counts, starts, lo, hi, smin = _full_tree_build(tree, storage, caps, keys,
                                                              valid, coords, scale)
        return ch.Hierarchy(tree, tuple(m), counts, storage, tuple(starts), tuple(lo),
                            tuple(hi), tuple(smin))

    scene, gbuf, light, _ = _setup("gate")
    runs = []
    for build in (real, reference):
        monkeypatch.setattr(ch, "build", build)
        runs.append(run_traversal_method(scene, gbuf, light, kind="cluster", precision="float32",
                                         shadow_eps=1e-5, bias="receiver")[0])
    new, old = runs
    np.testing.assert_array_equal(new.lit, old.lit)
    assert new.counters.keys() == old.counters.keys()
    for key, value in new.counters.items():
        np.testing.assert_array_equal(value, old.counters[key], err_msg=key)
    assert new.counters["trivial_accepts"] > 0 and new.counters["tests"] > 0


def test_build_on_duplicates_and_crowded_tiles():
    """Hand-made 16 x 16 image: a tile with 64 distinct clusters, a tile whose samples
    share one key, a tile with a few repeated keys, an empty tile, padding rows and bias
    scales of +-0: the build equals the full-tree reference."""
    cam = sl.Camera(eye=(0, 0, 5), target=(0, 0, 0), near=0.1, far=100, resolution=(16, 16))
    tree = ch.cluster_layout(cam, z_bits=6)
    rng = np.random.default_rng(7)
    py, px = np.divmod(np.arange(256), 16)
    keep = ~((px >= 8) & (py >= 8))                         # tile (1, 1) stays empty
    px, py = px[keep], py[keep]
    few = rng.integers(0, 3, len(px))
    z = np.where(px < 8, np.where(py < 8, (py % 8) * 8 + px % 8, 5), few)
    s, n = 256, len(px)
    pxs = np.concatenate([px, np.zeros(s - n, int)])
    pys = np.concatenate([py, np.zeros(s - n, int)])
    zs = np.concatenate([z, np.full(s - n, 9)])
    keys = ch.encode(tuple(jnp.asarray(v, jnp.uint32) for v in (pxs // 8, pys // 8, zs)),
                     tree.layout, xp=jnp)
    valid = jnp.arange(s) < n
    coords = jnp.asarray(rng.normal(size=(s, 3)), jnp.float32)
    scale = jnp.asarray(rng.choice([0.0, -0.0, 0.5, 2.0], s), jnp.float32)
    _, table = ch.tile_slots(tree, jnp.asarray(pxs, jnp.int32), jnp.asarray(pys, jnp.int32),
                             valid)
    for storage in ("compact", "full"):
        new = ch.build(tree, keys, valid, coords, scale, storage, **_tiles(keys, table))
        caps = _caps(tree, storage, 256)
        _assert_same_hierarchy(new, _full_tree_build(tree, storage, caps, keys, valid, coords,
                                                     scale), caps)
        assert int(new.counts[-1]) == 64 + 1 + len(np.unique(few[px >= 8]))


def test_memory_report_matches_the_paper():
    cam = sl.Camera(eye=(0, 0, 5), target=(0, 0, 0), near=0.1, far=1000,
                    resolution=(1024, 1024))
    tree = ch.cluster_layout(cam, z_bits=9)
    assert tree.key_bits == 23 and tree.levels == 5
    rep = ch.memory_report(tree)
    assert abs(rep["total_nodes"] / 1e6 - 8.65) < 0.01
    assert abs(rep["mask_bytes"] / 2**20 - 1.03) < 0.05            # ~1 MB of masks
    assert abs(rep["full_bounds_bytes"] / 2**20 - 198) < 1          # 198 MB of boxes
    assert abs(rep["pointer_bytes"] / 2**20 - 33) < 0.1             # 33 MB of pointers
    assert abs(rep["compact_worst_bytes"] / 2**20 - 25) < 1.5       # worst case ~25 MB
    hd = ch.cluster_layout(cam.replace(resolution=(1920, 1080)))
    assert hd.bits == (8, 8, 10) and hd.key_bits == 26              # one more bit each
    assert tree.saturates and ch.cluster_layout(cam, depth_slices="scaled").log_ratio > \
        tree.log_ratio


def test_keys_int32_rows_cannot_address_are_refused_before_the_traversal():
    """Keys of 31 or more bits would index the accepted-children rows past int32: the
    layout refuses them up front (the automatic z_bits stays within the limit)."""
    from shadowlab.core.capacity import CapacityError
    cam = sl.Camera(eye=(0, 0, 5), target=(0, 0, 0), near=0.1, far=1000,
                    resolution=(8192, 8192))
    auto = ch.cluster_layout(cam)
    assert auto.key_bits == ch.MAX_KEY_BITS == 30 and auto.bits == (10, 10, 10)
    with pytest.raises(CapacityError, match="31 bits.*at most 30"):
        ch.cluster_layout(cam, z_bits=11)
    scene, gbuf, light, _ = _setup("gate", 48)
    with pytest.raises(CapacityError, match="z_bits"):
        sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv", z_bits=25,
                           depth_slices="scaled")


def test_post_perspective_planes_orientation_and_shared_edges(precision):
    dtype = np.float64 if precision == "float64" else np.float32
    rng = np.random.default_rng(3)
    cam = sl.Camera(eye=(1, 2, 9), target=(0, 0, 0), near=0.5, far=60, resolution=(64, 48))
    a, b = rng.uniform(-2, 2, (2, 3))
    tris = np.array([[a, b, rng.uniform(-2, 2, 3)], [b, a, rng.uniform(-2, 2, 3)]])
    tris = np.concatenate([tris, rng.uniform(-2, 2, (30, 3, 3))])
    light = np.array([3.0, 9.0, 1.0, 1.0])
    from shadowlab.core.frame import precision_mode
    with precision_mode(precision):
        planes, valid = shadow_volume_planes(jnp.asarray(tris, dtype), jnp.asarray(light, dtype))
        planes = planes.reshape(-1, 4, 4)
        inv_view = jnp.asarray(np.linalg.inv(cam.view_matrix()), dtype)
        f = 1 / np.tan(np.radians(cam.fov_y_deg) / 2)
        g, tol = post_perspective_planes(planes, inv_view, jnp.asarray(2.0, dtype),
                                         jnp.asarray(3.0, dtype), extra="culling",
                                         p00=f / cam.aspect, p11=f)
        g = np.asarray(g, np.float64)
    planes = np.asarray(planes, np.float64)
    # same sign as the world plane and as the clip-space plane (the world plane times
    # inv(view_projection)), at random points in the frustum
    pts = rng.uniform(-3, 3, (200, 3))
    v = pts @ cam.view_matrix()[:3, :3].T + cam.view_matrix()[:3, 3]
    keep = -v[:, 2] > cam.near
    pts, v = pts[keep], v[keep]
    wq = -v[:, 2]
    npp = np.stack([f / cam.aspect * v[:, 0] / wq, f * v[:, 1] / wq, 1 / wq, np.ones(len(wq))], 1)
    world = np.einsum("tpi,si->tsp", planes[..., :3], pts) + planes[None, :, :, 3].transpose(1, 0, 2)
    post = np.einsum("tpi,si->tsp", g[:, :4], npp) * wq[None, :, None]
    np.testing.assert_allclose(post, world, rtol=1e-4, atol=1e-4 if dtype == np.float32 else 1e-9)
    clip = planes @ np.linalg.inv(cam.view_projection())
    hom = np.concatenate([pts, np.ones((len(pts), 1))], 1) @ cam.view_projection().T
    np.testing.assert_allclose(np.einsum("tpi,si->tsp", clip, hom), world, rtol=1e-4, atol=1e-4)
    # shared edge: exactly negated world planes give exactly negated post-perspective rows
    if np.asarray(valid)[:2].all() and np.array_equal(planes[0, 0], -planes[1, 0]):
        np.testing.assert_array_equal(g[0, 0], -g[1, 0])
    # extra culling planes: every point inside the volume is inside them
    inside = np.all(world[..., :3] >= 0, -1) & (world[..., 3] < 0)
    extra = np.einsum("tpi,si->tsp", g[:, 4:], npp)
    assert np.all(extra[inside] >= -1e-5)


# --------------------------------------------------------------------------- traversal

def _loop_traversal(det):
    """Algorithm 1 as a plain per-triangle depth-first loop (float64, no pruning)."""
    tree, h = det["tree"], det["hierarchy"]
    masks = [np.asarray(m) for m in h.masks]
    lo = [np.asarray(x, np.float64) for x in h.lo]
    hi = [np.asarray(x, np.float64) for x in h.hi]
    sm = [np.asarray(x, np.float64) for x in h.smin]
    ptr = None if h.ptr is None else [np.asarray(x) for x in h.ptr]
    g, tol = np.asarray(det["g"], np.float64), np.asarray(det["tol"], np.float64)
    bound = np.asarray(det["bound"], np.float64)
    smax = float(det["smax"])
    table = np.asarray(det["table"])
    n_s = int(det["sample_count"])
    u = np.finfo(np.float64).eps
    d = tree.levels
    out = dict(node_tests=0, trivial_accepts=0, trivial_rejects=0, leaf_visits=0, tests=0)
    iters = []
    for t in det["casters"]:
        count, stack = 0, [(0, 0)]
        while stack:
            level, node = stack.pop()
            count += 1
            if level == d:
                out["leaf_visits"] += 1
                x, y = [int(c) for c in ch.decode_np(node, tree)]
                out["tests"] += int(np.sum(table[y * tree.tiles_x + x] < len(det["scale"])))
                continue
            kids = [node * 32 + c for c in range(32) if (int(masks[level][node]) >> c) & 1]
            if not kids:
                continue
            kid = np.array(kids, np.uint32)
            idx = kid.astype(np.int64) if ptr is None else ptr[level][kid]
            blo, bhi, s = lo[level][idx], hi[level][idx], sm[level][idx]
            if not all(det["axes"]):
                # all 32 children at once (one array shape for every call: eager ops
                # compile per shape), then the existing ones
                every = np.uint32(node) * np.uint32(32) + np.arange(32, dtype=np.uint32)
                with jax.enable_x64(True):
                    ilo, ihi = ch.implicit_bounds(tree, level + 1, jnp.asarray(every),
                                                  np.float64)
                ax = np.array(det["axes"])
                blo = np.where(ax, blo, np.asarray(ilo)[kid % 32])
                bhi = np.where(ax, bhi, np.asarray(ihi)[kid % 32])
            for j, k in enumerate(kids):
                out["node_tests"] += 1
                vmax = [sum(max(g[t, r, a] * blo[j, a], g[t, r, a] * bhi[j, a]) for a in range(3))
                        + g[t, r, 3] for r in range(7)]
                vmin = [sum(min(g[t, r, a] * blo[j, a], g[t, r, a] * bhi[j, a]) for a in range(3))
                        + g[t, r, 3] for r in range(7)]
                rej = any(vmax[r] < -tol[t, r] for r in range(3)) or (
                    s[j] > 0 and vmin[3] - tol[t, 3] > 0) or (
                    det["bias_reject"] and s[j] > 0 and blo[j, 2] > 0
                    and ((vmin[3] - tol[t, 3]) / blo[j, 2]) * smax * (1 + 64 * u)
                    > bound[t] * (1 - 64 * u))
                cmax = vmax[3] + tol[t, 3]
                acc = (not rej and all(vmin[r] >= tol[t, r] for r in range(3)) and s[j] > 0
                       and cmax < 0 and (cmax / bhi[j, 2]) * s[j] * (1 - 64 * u)
                       < bound[t] * (1 + 64 * u))
                if not rej and not acc and det["extra"] != "none":
                    rej = any(vmax[r] < -tol[t, r] for r in range(4, 7))
                if rej:
                    out["trivial_rejects"] += 1
                elif acc:
                    out["trivial_accepts"] += 1
                else:
                    stack.append((level + 1, k))
        iters.append(count)
    return out, np.array(iters)


@pytest.mark.parametrize("method,opts,two", [
    ("cluster", dict(bounds="explicit", front_face_culling=False), True),
    ("cluster", dict(bounds="explicit", bias_reject=True), False),
    ("cluster", dict(bounds="implicit", storage="full"), False),
    ("ptsv", dict(), False)])
def test_traversal_counters_against_a_loop(method, opts, two):
    scene = sl.load_scene("gate", trees=2, leaves_per_tree=12, bars=3)
    view = default_view("gate", scene, trees=2, leaves_per_tree=12, bars=3)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(RES, RES)))
    res, det = run_traversal_method(scene, gbuf, view.light, kind=method, precision="float64",
                                    shadow_eps=1e-5, bias="receiver", **opts)
    want, iters = _loop_traversal(det)
    for key, value in want.items():
        assert res.counters[key] == value, key
    np.testing.assert_array_equal(det["iterations_pass1"], iters)
    if not two:
        return
    # two passes: same work, split into (triangle, node) jobs
    res2, det2 = run_traversal_method(scene, gbuf, view.light, kind=method, precision="float64",
                                      shadow_eps=1e-5, bias="receiver", passes=2,
                                      expand_level=2, **opts)
    for key in want:
        assert res2.counters[key] == res.counters[key], key
    assert det2["iterations_pass1"].sum() + det2["iterations_pass2"].sum() == iters.sum()
    assert np.array_equal(res2.lit, res.lit)


def test_frontier_buckets_are_remembered_per_scene(monkeypatch):
    """The traversal's frontier buckets are remembered per scene: a scene whose frontier
    grew a bucket does not hand it to another scene (every level clears and fills whole
    buckets, so a larger one costs time), and a scene's own later frames reuse its own."""
    import shadowlab.methods.clustered_ptsv as cp

    seen = []
    real = cp.traverse

    def spy(*args, buckets=None, **kwargs):
        before = dict(buckets)
        out = real(*args, buckets=buckets, **kwargs)
        seen.append((buckets, before, dict(buckets)))
        return out

    monkeypatch.setattr(cp, "traverse", spy)
    small, big = _setup("gate", 16), _setup("fuzzy", 96)
    for scene, gbuf, light, _ in (small, big, small):
        sl.compute_shadows(scene, gbuf, light, method="ptsv")
    (a1, a_before, a_after), (b, b_before, b_after), (a2, a2_before, _) = seen
    assert a1 is a2 and b is not a1 and not a_before and not b_before
    assert max(b_after.values()) > max(a_after.values())     # the big scene grew its own
    assert a2_before == a_after                              # the small one kept its own


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_reused_setup_gives_the_same_result(precision):
    """reuse_setup keeps the light's triangle setup (face culling, world-space planes):
    the next call with the same scene, light, precision and culling reuses it, on either
    tree, and equals a run that sets up; another light or culling side, or a dropped
    cache, sets up anew."""
    from shadowlab.scene import caches

    scene, gbuf, light, _ = _setup("gate")          # a scene of its own: nothing cached
    kw = dict(precision=precision, shadow_eps=1e-5, bias="receiver")

    def run(kind, lamp=light, **o):
        return run_traversal_method(scene, gbuf, lamp, kind=kind, **kw, **o)

    def same(a, b):
        assert np.array_equal(a.lit, b.lit)
        for k in a.counters:
            assert np.array_equal(np.asarray(a.counters[k]), np.asarray(b.counters[k])), k

    for kind in ("cluster", "ptsv"):
        fresh, _ = run(kind)
        first, d1 = run(kind, reuse_setup=True)
        again, d2 = run(kind, reuse_setup=True)
        assert d2["planes"] is d1["planes"] and d2["scene"] is d1["scene"]
        assert again.counters["front_face_culled"] == fresh.counters["front_face_culled"] > 0
        same(fresh, first)
        same(fresh, again)
    _, d3 = run("ptsv", reuse_setup=True, cull_side="facing")
    assert d3["planes"] is not d1["planes"]
    moved = sl.PointLight(position=np.asarray(light.position) + [0.5, 0.0, 0.0])
    other, d4 = run("cluster", moved, reuse_setup=True)
    assert d4["planes"] is not d3["planes"]
    same(run("cluster", moved)[0], other)
    assert run("cluster", moved, reuse_setup=True)[1]["planes"] is d4["planes"]
    caches.drop(scene)
    assert run("cluster", moved, reuse_setup=True)[1]["planes"] is not d4["planes"]


def test_top_jobs_are_the_largest_counts_descending():
    """The selection equals a plain sort's head, zero-padded, at sizes around k."""
    rng = np.random.default_rng(5)
    k = clustered.TOP_JOBS
    for n in (0, 1, k - 1, k, k + 1, 5 * k):
        for high in (3, 10**6):                 # many ties, few ties
            x = rng.integers(0, high, n)
            want = np.zeros(k, np.int64)
            head = sorted(x.tolist(), reverse=True)[:k]
            want[: len(head)] = head
            assert np.array_equal(clustered.top_jobs(x), want), (n, high)
