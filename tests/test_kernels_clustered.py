"""Clustered PTSV kernels (Warp, CPU backend) against the JAX method and the Embree
reference: setup and hierarchy bit for bit, lit masks, every integer counter, the
iterations of every job (per caster; per (triangle, node) job in two passes)."""

import functools

import numpy as np
import pytest

wp = pytest.importorskip("warp")

import shadowlab as sl
from shadowlab.kernels import clustered_ptsv as kc
from shadowlab.methods.clustered_ptsv import run_traversal_method
from shadowlab.methods.registry import call_options, resolve_options
from shadowlab.scene.procedural import default_view

SCENES = {
    "gate": ({"trees": 3, "leaves_per_tree": 60, "bars": 4}, 64),
    "sphere_grid": ({"n": 3, "triangles_per_sphere": 120}, 32),
    "soup": ({"count": 80}, 64),
}


@functools.cache
def _scene(name, directional=False):
    params, res = SCENES[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    light = view.light
    if directional:
        centre = scene.triangles.reshape(-1, 3).mean(0)      # light travels the same way
        light = sl.DirectionalLight(direction=centre - np.asarray(light.position, float))
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    return scene, light, gbuf, sl.reference_shadows(scene, gbuf, light)


_JAX = {}


def _jax(name, directional=False, **opts):
    key = (name, directional, tuple(sorted(opts.items())))
    if key not in _JAX:
        scene, light, gbuf, _ = _scene(name, directional)
        o = call_options("clustered_ptsv", opts)
        _JAX[key] = run_traversal_method(scene, gbuf, light, kind="cluster",
                                         method="clustered_ptsv", options=o, **o)
    return _JAX[key]


def _differing(j, k):
    """Counters of the kernel result that differ from the JAX result."""
    return [c for c, v in k.counters.items()
            if not np.array_equal(np.asarray(v), np.asarray(j.counters[c]))]


def _pass2_jobs(tri, node, iters):
    return {(int(t), int(n)): int(i) for t, n, i in zip(tri, node, iters)}


def _check_equal(name, form, directional=False, job_order=None, **opts):
    scene, light, gbuf, truth = _scene(name, directional)
    j, det = _jax(name, directional, **opts)
    k, kd = kc.run_details(scene, gbuf, light, form=form, job_order=job_order, **opts)
    assert np.array_equal(k.lit, j.lit)
    assert _differing(j, k) == []
    assert set(j.counters) - set(k.counters) == {"frontier_max"}
    np.testing.assert_array_equal(kd["iterations_pass1"], det["iterations_pass1"])
    if resolve_options("clustered_ptsv", opts)["passes"] == 2:
        want = _pass2_jobs(det["pass2_triangles"], det["pass2_nodes"], det["iterations_pass2"])
        got = _pass2_jobs(kd["pass2_triangles"], kd["pass2_nodes"], kd["iterations_pass2"])
        assert len(want) == len(det["pass2_triangles"]) and got == want
    assert np.count_nonzero((k.lit != truth) & gbuf.valid) == 0
    return k, kd


@pytest.mark.parametrize("name", list(SCENES))
def test_setup_is_bit_exact(name):
    """The setup kernel equals the JAX setup bit for bit: world planes and validity
    (``shadow_volume_planes``), post-perspective rows, extra planes and tolerances
    (``post_perspective_planes``), both as the JAX method computes them (triangles
    padded to its capacity) and on the unpadded triangles; keys and casters too."""
    import jax.numpy as jnp

    from shadowlab.geometry.triangle_setup import shadow_volume_planes as setup
    from shadowlab.geometry.volume_planes import post_perspective_planes
    from shadowlab.scene.view import hard_light

    scene, light, gbuf, _ = _scene(name)
    _, det = _jax(name)
    p = kc.prepare(scene, gbuf, light, call_options("clustered_ptsv", {}))
    # both drop the light-averted triangles of closed objects first (the default)
    assert p["face_culled"] == scene.num_triangles - p["scene"].num_triangles
    scene = p["scene"]
    n = scene.num_triangles
    f32 = np.float32
    assert p["planes"].dtype == f32 and np.asarray(det["planes"]).shape[0] > n   # padded
    np.testing.assert_array_equal(p["planes"], np.asarray(det["planes"])[:n])
    np.testing.assert_array_equal(p["g"], np.asarray(det["g"])[:n])
    np.testing.assert_array_equal(p["tol"], np.asarray(det["tol"])[:n])
    np.testing.assert_array_equal(p["bound"], np.asarray(det["bound"])[:n])
    assert 0 < p["valid"].sum() and p["g"][:, 4:].any()
    # unpadded JAX setup: the same values (no shape-dependent rounding)
    light_h = hard_light(light).homogeneous
    planes, valid = setup(jnp.asarray(scene.triangles.astype(f32)),
                          jnp.asarray(light_h.astype(f32)))
    np.testing.assert_array_equal(p["valid"], np.asarray(valid))
    np.testing.assert_array_equal(p["planes"], np.asarray(planes))
    tree = p["tree"]
    inv_view = jnp.asarray(np.linalg.inv(gbuf.camera.view_matrix()).astype(f32))
    qmax, pmax = f32(p["coords"][:, 2].max()), f32(np.abs(p["samples"].position).max())
    g, tol = post_perspective_planes(planes.reshape(-1, 4, 4), inv_view, jnp.asarray(qmax),
                                     jnp.asarray(pmax), extra="culling", p00=tree.p00,
                                     p11=tree.p11)
    np.testing.assert_array_equal(p["g"], np.asarray(g))
    np.testing.assert_array_equal(p["tol"], np.asarray(tol))
    # the post-perspective part alone, from given world planes
    q = kc.triangle_setup(scene.triangles.astype(f32), light_h, gbuf.camera, tree, qmax, pmax,
                          world_planes=(np.asarray(planes), np.asarray(valid)))
    np.testing.assert_array_equal(q["g"], np.asarray(g))
    np.testing.assert_array_equal(q["tol"], np.asarray(tol))
    np.testing.assert_array_equal(p["keys"], np.asarray(det["keys"])[: len(p["keys"])])
    np.testing.assert_array_equal(p["casters"], det["casters"])


@pytest.mark.parametrize("storage", ["compact", "full"])
@pytest.mark.parametrize("form", kc.FORMS)
def test_hierarchy_equals_jax(storage, form):
    scene, light, gbuf, _ = _scene("gate")
    _, det = _jax("gate", storage=storage)
    p = kc.prepare(scene, gbuf, light, call_options("clustered_ptsv", {"storage": storage}))
    h = kc.build_hierarchy(p["tree"], p["table"], p["keys"], p["coords"], p["scale"], storage,
                           form).host()
    jh = det["hierarchy"]
    assert h["counts"] == list(jh.counts)
    for lvl in range(p["tree"].levels):
        np.testing.assert_array_equal(h["masks"][lvl], np.asarray(jh.masks[lvl]))
        exists = np.asarray(jh.exists[lvl])
        if storage == "compact":
            np.testing.assert_array_equal(h["ptr"][lvl], np.asarray(jh.ptr[lvl]))
            rows = np.arange(jh.counts[lvl])
        else:
            rows = np.flatnonzero(exists)
        for a in ("lo", "hi", "smin"):
            np.testing.assert_array_equal(h[a][lvl][rows], np.asarray(getattr(jh, a)[lvl])[rows])


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("form", kc.FORMS)
def test_method_equals_jax_and_reference(name, form):
    k, _ = _check_equal(name, form)
    assert k.counters["tests"] > 0 and k.counters["node_tests"] > 0
    if name == "gate":                          # the default culls the averted side
        assert k.counters["front_face_culled"] > 0


@pytest.mark.parametrize("opts", [
    {"bounds": "implicit", "culling_planes": False},
    {"storage": "full", "passes": 2, "expand_level": 2},
    {"front_face_culling": False},
    {"passes": 2, "expand_level": 5, "front_face_culling": False},
    {"front_face_culling": True, "cull_side": "facing"},
    {"bias": "cap", "leaf_samples": "cluster", "depth_slices": "scaled"},
    {"z_bits": 4, "bounds": "implicit", "passes": 2, "expand_level": 3},
])
def test_options_equal_jax(opts):
    for form in kc.FORMS:
        k, _ = _check_equal("gate", form, **opts)
        if opts == {"front_face_culling": False}:   # the unculled gate accepts nodes
            assert k.counters["trivial_accepts"] > 0


def test_directional_light_equals_jax():
    for form in kc.FORMS:
        _check_equal("soup", form, directional=True)
        _check_equal("gate", form, directional=True, passes=2, expand_level=3)


def test_job_order_does_not_matter_without_pruning():
    """Without pruning every counter is a sum over jobs that do not interact: another
    job order (a GPU's schedule) gives the same counters and per-job iterations."""
    casters = _jax("gate")[1]["casters"]
    order = np.random.default_rng(0).permutation(len(casters))
    _check_equal("gate", "warp", job_order=order)
    _check_equal("gate", "lanes", job_order=order[::-1].copy(), passes=2, expand_level=3)


def test_pruning_in_serial_order_equals_waves_of_one():
    """With pruning the kernel sees every accept at once (atomic AND); in the serial job
    order that is the JAX schedule with waves of one job: everything equal."""
    for form in kc.FORMS:
        _check_equal("gate", form, prune=True, wave=1)
        _check_equal("soup", form, prune=True, wave=1)


def test_pruning_counters_depend_on_the_schedule():
    """With pruning, counters depend on when accepts become visible; the shadows do not.
    (Unculled: the gate's accepts come from light-averted triangles at this size.)"""
    scene, light, gbuf, truth = _scene("gate")
    unculled = {"front_face_culling": False}
    j, _ = _jax("gate", prune=True, wave=512, **unculled)
    serial = kc.run(scene, gbuf, light, form="warp", prune=True, **unculled)
    order = np.arange(j.counters["casters"])[::-1].copy()
    reverse = kc.run(scene, gbuf, light, form="warp", prune=True, job_order=order, **unculled)
    for k in (serial, reverse):
        assert np.array_equal(k.lit, j.lit)
        assert np.count_nonzero((k.lit != truth) & gbuf.valid) == 0
    # accepts seen sooner prune more: never more node tests than the JAX waves
    assert serial.counters["node_tests"] < j.counters["node_tests"]
    assert serial.counters["node_tests"] != reverse.counters["node_tests"]
    unpruned, _ = _jax("gate", **unculled)
    assert serial.counters["node_tests"] < unpruned.counters["node_tests"]


def test_float64_is_refused():
    scene, light, gbuf, _ = _scene("soup")
    with pytest.raises(ValueError, match="float32"):
        kc.run(scene, gbuf, light, precision="float64")


@wp.kernel
def _child_codes(word: wp.array(dtype=wp.uint32), g: wp.array3d(dtype=wp.float32),
                 tol: wp.array2d(dtype=wp.float32), bound: wp.array(dtype=wp.float32),
                 lo: wp.array2d(dtype=wp.float32), hi: wp.array2d(dtype=wp.float32),
                 smin: wp.array(dtype=wp.float32), i32: wp.array(dtype=wp.int32),
                 f32: wp.array(dtype=wp.float32), codes: wp.array2d(dtype=wp.int32)):
    """Job j (triangle j, node j of level 0, full storage, explicit boxes), lane l."""
    j, lane = wp.tid()
    child = (wp.uint32(j) << wp.uint32(5)) | wp.uint32(lane)
    codes[j, lane] = kc._test_child(word[j], wp.uint32(1) << wp.uint32(lane), j, 0, child, 5, 1,
                                    i32, wp.vec3i(1, 1, 1), f32, f32, i32, 0, i32, i32, i32, lo,
                                    hi, smin, g, tol, bound, 1)


def test_node_test_rounds_as_jax_on_ties():
    """The kernels' node test against the JAX one on boxes placed exactly on a plane's
    rejection threshold (the threshold is the JAX order's value, so any other rounding
    of the box extremes flips the decision): every child's code is equal."""
    import jax.numpy as jnp

    from shadowlab.methods.clustered_ptsv import _test_children

    rng = np.random.default_rng(7)
    n, f32 = 512, np.float32
    g = rng.uniform(-1, 1, (n, 7, 4)).astype(f32)
    lo = rng.uniform(-1, 1, (n * 32, 3)).astype(f32)
    hi = (lo + rng.uniform(0, 0.5, (n * 32, 3))).astype(f32)
    lo[:, 2], hi[:, 2] = np.abs(lo[:, 2]) + f32(0.1), np.abs(hi[:, 2]) + f32(0.7)
    smin = rng.uniform(0.5, 2, n * 32).astype(f32)
    bound = rng.uniform(-1, 1, n).astype(f32)
    word = np.full(n, 0xFFFFFFFF, np.uint32)
    word[::7] = rng.integers(0, 2**32, len(word[::7]), dtype=np.uint32)

    def extreme(t, r, c, pick, order):          # float32, axes summed in ``order``
        b = t * 32 + c
        v = [pick(g[t, r, a] * lo[b, a], g[t, r, a] * hi[b, a]) for a in range(3)]
        return ((v[order[0]] + v[order[1]]) + v[order[2]]) + g[t, r, 3]

    tol = np.full((n, 7), 1e6, f32)               # no row decides ...
    flips = 0
    for t in range(n):                            # ... but one, exactly at its threshold
        r, c = int(rng.choice([0, 1, 2, 3, 4, 5, 6])), int(rng.integers(32))
        if r == 3:                                # cap reject: vmin - tol > 0
            tol[t, r] = extreme(t, r, c, np.minimum, (0, 2, 1))
            flips += extreme(t, r, c, np.minimum, (0, 1, 2)) - tol[t, r] > 0
        else:                                     # edge / extra reject: vmax < -tol
            tol[t, r] = -extreme(t, r, c, np.maximum, (0, 2, 1))
            flips += extreme(t, r, c, np.maximum, (0, 1, 2)) < -tol[t, r]
    assert flips > 10                             # the x + y + q order would differ here

    cfg = {"axes": (True, True, True), "storage": "full", "extra": True, "prune": False,
           "bias_reject": False}
    a = {"g": jnp.asarray(g), "tol": jnp.asarray(tol), "bound": jnp.asarray(bound),
         "masks": jnp.asarray(word), "lo": jnp.asarray(lo), "hi": jnp.asarray(hi),
         "smin": jnp.asarray(smin),
         "off": {"masks": jnp.zeros(1, jnp.int32), "boxes": jnp.zeros(1, jnp.int32)}}
    idx = jnp.arange(n, dtype=jnp.int32)
    exists, accept, reject, extra, inter = (np.asarray(x) for x in _test_children(
        cfg, 0, a, idx, idx.astype(jnp.uint32), jnp.ones(n, bool), jnp.zeros((1, 32), bool)))
    want = np.select([~exists, accept, extra, reject, inter], [4, 0, 2, 1, 3], -1)
    assert (want >= 0).all() and {1, 2, 3, 4} <= set(np.unique(want))

    dev = kc.init()
    arr = lambda x: kc._arr(x, x.dtype, dev)
    codes = wp.zeros((n, 32), dtype=wp.int32, device=dev)
    wp.launch(_child_codes, dim=(n, 32), device=dev, inputs=[
        arr(word), arr(g), arr(tol), arr(bound), arr(lo), arr(hi), arr(smin),
        wp.zeros(1, dtype=wp.int32, device=dev), wp.zeros(1, dtype=wp.float32, device=dev),
        codes])
    np.testing.assert_array_equal(codes.numpy(), want)
